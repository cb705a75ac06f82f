//! Criterion benchmarks of the core (run with `cargo bench`; single thread, release):
//! index build, one nearest-neighbour query, and one ICP alignment of a 361-beam scan
//! (180°, 0.5°, 1 cm noise, 20% of beams on unmapped obstacles) against an office map of
//! 1k / 10k / 100k / 1M points from an initial error of (0.3 m, 0.3 m, 10°).
//! Before timing each map size it prints the success rate (within 2 cm and 0.5°) and the
//! median time of one pass over the 200 cases; criterion then times repeated passes.
//! From the large start error (1.0 m, 0.5 m, 25°) the heading search (±30°, 10° steps) is on.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use icploc_core::index::DEFAULT_CACHE_RESOLUTION;
use icploc_core::se2::wrap_angle;
use icploc_core::testkit::{cases, office_segments, sample_segments, Case};
use icploc_core::{align, IcpConfig, MapIndex, Metric};

const SIZES: [usize; 4] = [1_000, 10_000, 100_000, 1_000_000];

fn total_length() -> f64 {
    office_segments()
        .iter()
        .map(|s| ((s[2] - s[0]).powi(2) + (s[3] - s[1]).powi(2)).sqrt())
        .sum()
}

fn map_of(n: usize) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    sample_segments(&office_segments(), total_length() / n as f64)
}

/// The map index as the Python API builds it by default (with the closest-point grid).
fn cached_index(n: usize) -> MapIndex {
    let (p, nrm) = map_of(n);
    MapIndex::new(p, Some(nrm))
        .unwrap()
        .with_cache(Some(DEFAULT_CACHE_RESOLUTION))
        .unwrap()
}

/// 1,024 fixed query points spread over the office.
fn queries() -> Vec<[f64; 2]> {
    (0..1024)
        .map(|i| [(i as f64 * 0.37) % 30.0, (i as f64 * 0.71) % 20.0])
        .collect()
}

fn success(idx: &MapIndex, cs: &[Case], cfg: &IcpConfig) -> (usize, Duration) {
    let mut ok = 0;
    let mut times: Vec<Duration> = Vec::with_capacity(cs.len());
    for c in cs {
        let t0 = Instant::now();
        let r = align(&c.scan, idx, c.initial, cfg).expect("valid input");
        times.push(t0.elapsed());
        let dt = ((r.pose.x - c.truth.x).powi(2) + (r.pose.y - c.truth.y).powi(2)).sqrt();
        let dth = wrap_angle(r.pose.theta - c.truth.theta).abs();
        if dt < 0.02 && dth < 0.5f64.to_radians() {
            ok += 1;
        }
    }
    times.sort();
    (ok, times[times.len() / 2])
}

fn bench_build(c: &mut Criterion) {
    let mut g = c.benchmark_group("index_build");
    g.sample_size(10);
    for &n in &SIZES {
        let (p, nrm) = map_of(n);
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                MapIndex::new(black_box(p.clone()), Some(nrm.clone()))
                    .unwrap()
                    .with_cache(Some(DEFAULT_CACHE_RESOLUTION))
                    .unwrap()
            })
        });
    }
    g.finish();
}

fn bench_nearest(c: &mut Criterion) {
    let mut g = c.benchmark_group("nearest_one");
    for &n in &SIZES {
        let (p, nrm) = map_of(n);
        let idx = MapIndex::new(p, Some(nrm)).unwrap();
        let qs = queries();
        let mut k = 0usize;
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                k = (k + 1) & 1023;
                black_box(idx.nearest(black_box(qs[k])))
            })
        });
    }
    g.finish();
}

fn bench_correspondence(c: &mut Criterion) {
    // the query ICP makes: through the precomputed nearest-point cache
    let mut g = c.benchmark_group("correspondence_cached");
    for &n in &SIZES {
        let idx = cached_index(n);
        let qs = queries();
        let mut k = 0usize;
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                k = (k + 1) & 1023;
                black_box(idx.correspondence(black_box(qs[k])))
            })
        });
    }
    g.finish();
}

fn bench_align(c: &mut Criterion) {
    let segs = office_segments();
    for (name, err) in [
        ("small", (0.3, 0.3, 10f64.to_radians())),
        ("large", (1.0, 0.5, 25f64.to_radians())),
    ] {
        let cs = cases(&segs, 200, err, 0.01, 0.2, 7);
        for metric in [Metric::PointToLine, Metric::PointToPoint] {
            // from the large start error, search start headings ±30° every 10°
            let search = if name == "large" {
                30f64.to_radians()
            } else {
                0.0
            };
            let cfg = IcpConfig {
                metric,
                heading_search: search,
                heading_step: 10f64.to_radians(),
                ..IcpConfig::default()
            };
            let mut g = c.benchmark_group(format!("align_{name}_{metric:?}"));
            for &n in &SIZES {
                let idx = cached_index(n);
                let (ok, med) = success(&idx, &cs, &cfg);
                eprintln!(
                    "align {name} start error, {metric:?}, {n} map points: {ok}/{} within 2 cm and 0.5° ({:.1}%), median {:?}",
                    cs.len(),
                    100.0 * ok as f64 / cs.len() as f64,
                    med
                );
                let mut k = 0usize;
                g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
                    b.iter(|| {
                        k = (k + 1) % cs.len();
                        let c = &cs[k];
                        black_box(align(black_box(&c.scan), &idx, c.initial, &cfg).unwrap())
                    })
                });
            }
            g.finish();
        }
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3));
    targets = bench_build, bench_nearest, bench_correspondence, bench_align
}
criterion_main!(benches);
