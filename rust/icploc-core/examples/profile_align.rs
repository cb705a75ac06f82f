//! A loop of default `align()` calls over one family's cases, in the benchmark's order
//! (each case once per pass, so each call starts with caches holding the previous
//! case's part of the map), for a profiler:
//! `cargo run --release --example profile_align -- clinic small 20` (family, start, passes).
//! Prints the median and p95 of each case's fastest pass and the cache's size.
use std::hint::black_box;
use std::time::{Duration, Instant};

use icploc_core::index::DEFAULT_CACHE_RESOLUTION;
use icploc_core::testkit::{all_worlds, sample_segments, unseen_worlds, world_cases};
use icploc_core::{align, IcpConfig, MapIndex, StartPath};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let family = args.get(1).map_or("clinic", |s| s.as_str());
    let start = args.get(2).map_or("small", |s| s.as_str());
    let passes: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(20);
    let err = if start == "large" {
        (1.0, 0.5, 25f64.to_radians())
    } else {
        (0.3, 0.3, 10f64.to_radians())
    };
    let w = all_worlds()
        .into_iter()
        .chain(unseen_worlds())
        .find(|w| w.name == family)
        .expect("a family name");
    let (p, nrm) = sample_segments(&w.map_segments(), 0.025);
    let idx = MapIndex::new(p, Some(nrm))
        .unwrap()
        .with_cache(Some(
            std::env::var("RES")
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(DEFAULT_CACHE_RESOLUTION),
        ))
        .unwrap();
    idx.likelihood_field()
        .expect("the map fits the window grid");
    idx.objects();
    // PLAIN=1: the plain ICP alone (no verified start)
    let cfg = IcpConfig {
        window_search: std::env::var_os("PLAIN").is_none(),
        ..IcpConfig::default()
    };
    let mut cs = world_cases(&w, 200, err, 7);
    // FAST=1: only the cases whose result came from the fast path (the plain ICP or the
    // one from the heading prior, no window search)
    if std::env::var_os("FAST").is_some() {
        cs.retain(|c| {
            let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
            matches!(r.start, StartPath::Plain | StartPath::Prior)
        });
    }
    // GROUP=fast (or slow): only the cases that take under (at least) 2.5 times the
    // fastest case's time (fastest of 3 warm calls each): the fast path's cases, which set
    // the median, apart from those with the look along a corridor or the window
    if let Ok(g) = std::env::var("GROUP") {
        let warm: Vec<Duration> = cs
            .iter()
            .map(|c| {
                (0..3)
                    .map(|_| {
                        let t0 = Instant::now();
                        black_box(align(&c.scan, &idx, c.initial, &cfg).unwrap());
                        t0.elapsed()
                    })
                    .min()
                    .expect("three calls")
            })
            .collect();
        let cut = warm.iter().min().copied().unwrap_or_default() * 5 / 2;
        let mut k = 0;
        cs.retain(|_| {
            k += 1;
            (warm[k - 1] < cut) == (g == "fast")
        });
        eprintln!("GROUP={g}: {} cases", cs.len());
    }
    // ONLY=k: case k alone (for a profile of one case)
    if let Some(k) = std::env::var("ONLY")
        .ok()
        .and_then(|s| s.parse::<usize>().ok())
    {
        cs = vec![cs.swap_remove(k)];
    }
    // DUMP=1: every case's result, bit for bit (to compare builds)
    if std::env::var_os("DUMP").is_some() {
        for (k, c) in cs.iter().enumerate() {
            let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
            let f = r
                .fit
                .map(|f| (f.inlier_ratio, f.rms, f.see_through, f.vanished, f.score));
            println!(
                "{k} {:016x} {:016x} {:016x} {} {} {:?} {f:?}",
                r.pose.x.to_bits(),
                r.pose.y.to_bits(),
                r.pose.theta.to_bits(),
                r.iterations,
                r.inliers,
                r.start
            );
        }
        return;
    }
    // CASE=k: the fit along the corridor through case k's truth and its result
    if let Some(k) = std::env::var("CASE")
        .ok()
        .and_then(|s| s.parse::<usize>().ok())
    {
        let c = &cs[k];
        let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
        let (dx, dy) = (r.pose.x - c.truth.x, r.pose.y - c.truth.y);
        println!(
            "case {k}: truth {:?}, result {:?} ({:?}, degeneracy {:.3}, direction {:?}), off ({dx:+.3}, {dy:+.3}) m",
            c.truth, r.pose, r.start, r.degeneracy, r.degenerate_direction
        );
        let len = dx.hypot(dy).max(1e-9);
        let u = [dx / len, dy / len];
        for i in -20..=20 {
            let d = i as f64 * 0.05;
            let p =
                icploc_core::Pose2::new(c.truth.x + d * u[0], c.truth.y + d * u[1], c.truth.theta);
            let f = icploc_core::icp::assess(&c.scan, &idx, p, &cfg);
            // ICP from there: where does it settle
            let plain = IcpConfig {
                window_search: false,
                ..cfg.clone()
            };
            let rr = align(&c.scan, &idx, p, &plain).unwrap();
            let e = (rr.pose.x - c.truth.x).hypot(rr.pose.y - c.truth.y);
            println!(
                "  {d:+.2} m along: inliers {:.3} rms {:.4} see-through {:.3} score {:.4}; ICP from there ends {e:.3} m from the truth",
                f.inlier_ratio, f.rms, f.see_through, f.score
            );
        }
        return;
    }
    // LOOKUPS=1: only the correspondence look-ups of each case's scan at its true pose
    if std::env::var_os("LOOKUPS").is_some() {
        let qs: Vec<Vec<[f64; 2]>> = cs
            .iter()
            .map(|c| c.scan.iter().map(|p| c.truth.transform(*p)).collect())
            .collect();
        let mut best = vec![Duration::MAX; cs.len()];
        for _ in 0..passes {
            for (k, q) in qs.iter().enumerate() {
                let t0 = Instant::now();
                let mut acc = 0.0;
                for p in q {
                    acc += idx.correspondence(*p).0;
                }
                black_box(acc);
                best[k] = best[k].min(t0.elapsed());
            }
        }
        let n: usize = qs.iter().map(|q| q.len()).sum();
        let total: Duration = best.iter().sum();
        println!(
            "{family}: {:.1} ns per look-up (case order, fastest of {passes} passes per case)",
            total.as_nanos() as f64 / n as f64
        );
        return;
    }
    // REPEAT=k: each case k times in a row (warm caches), in each pass
    let repeat: usize = std::env::var("REPEAT")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    // FLUSH=mb: before each timed call, write a buffer of that many MB (evicts the map's
    // data from the caches, not the branch predictors' history of a repeated case)
    let mut flush = vec![
        0u64;
        std::env::var("FLUSH")
            .ok()
            .and_then(|s| s.parse::<usize>().ok())
            .unwrap_or(0)
            << 17
    ];
    let mut times = vec![Duration::MAX; cs.len()];
    for _ in 0..passes {
        for (k, c) in cs.iter().enumerate() {
            for _ in 0..repeat {
                for v in flush.iter_mut() {
                    *v = v.wrapping_add(1);
                }
                black_box(&flush);
                let t0 = Instant::now();
                black_box(timed(&c.scan, &idx, c.initial, &cfg));
                times[k] = times[k].min(t0.elapsed());
            }
        }
    }
    if std::env::var_os("STATS").is_some() {
        let mut its: Vec<usize> = Vec::new();
        let mut paths = std::collections::BTreeMap::<String, usize>::new();
        let mut terms = std::collections::BTreeMap::<String, usize>::new();
        for c in &cs {
            let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
            its.push(r.iterations);
            *paths.entry(r.start.as_str().to_string()).or_default() += 1;
            *terms.entry(r.termination.as_str().to_string()).or_default() += 1;
        }
        its.sort();
        println!(
            "iterations of the last ICP: median {}, p95 {}; paths {paths:?}; terminations {terms:?}",
            its[its.len() / 2],
            its[its.len() * 95 / 100]
        );
    }
    // TIMES=1: each case's fastest time and path, fastest first (what the median is made of)
    if std::env::var_os("TIMES").is_some() {
        let mut order: Vec<usize> = (0..cs.len()).collect();
        order.sort_by_key(|&k| times[k]);
        for (rank, &k) in order.iter().enumerate() {
            let r = align(&cs[k].scan, &idx, cs[k].initial, &cfg).unwrap();
            println!(
                "{rank} case {k}: {:?} {} ({} iterations)",
                times[k],
                r.start.as_str(),
                r.iterations
            );
        }
    }
    times.sort();
    println!(
        "{family} {start}: {} cases, {} map points, grid {} KB in {} tiles; median {:?}, p95 {:?}",
        cs.len(),
        idx.len(),
        idx.cache_bytes() / 1024,
        idx.cache_tiles(),
        times[times.len() / 2],
        times[times.len() * 95 / 100]
    );
}

/// The timed call, not inlined: `valgrind --tool=callgrind --toggle-collect=profile_align::timed`
/// counts the timed calls alone (not the filters' or the other modes' calls).
#[inline(never)]
fn timed(
    scan: &[[f64; 2]],
    idx: &MapIndex,
    initial: icploc_core::Pose2,
    cfg: &IcpConfig,
) -> icploc_core::IcpResult {
    align(scan, idx, initial, cfg).unwrap()
}
