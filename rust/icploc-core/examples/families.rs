//! Success and timing of `align()` with the default config on the four families
//! (a quick table; `cargo bench` is the benchmark):
//! `cargo run --release --example families [n] [seed]`; `ONLY=clinic` one family,
//! `VERBOSE=1` prints every miss, `PATHS=1` the plain fit's verdict per case.
use std::time::Instant;

use icploc_core::index::DEFAULT_CACHE_RESOLUTION;
use icploc_core::se2::wrap_angle;
use icploc_core::testkit::{all_worlds, sample_segments, world_cases};
use icploc_core::{align, IcpConfig, MapIndex, StartPath};

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(200);
    let seed: u64 = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(7);
    let cfg = IcpConfig::default();
    let only = std::env::var("ONLY").ok();
    let f = |x: &icploc_core::Fit| {
        format!(
            "{:.2}/{:.4}/{:.2}/{:.3}",
            x.inlier_ratio, x.rms, x.see_through, x.score
        )
    };
    for w in all_worlds() {
        if only.as_deref().is_some_and(|o| o != w.name) {
            continue;
        }
        let (p, nrm) = sample_segments(&w.map_segments(), 0.025);
        let idx = MapIndex::new(p, Some(nrm))
            .unwrap()
            .with_cache(Some(DEFAULT_CACHE_RESOLUTION))
            .unwrap();
        let t = Instant::now();
        idx.likelihood_field()
            .expect("the map fits the window grid");
        let build = t.elapsed();
        for (name, err) in [
            ("small", (0.3, 0.3, 10f64.to_radians())),
            ("large", (1.0, 0.5, 25f64.to_radians())),
        ] {
            if std::env::var("START").is_ok_and(|s| s != name) {
                continue;
            }
            let mut cs = world_cases(&w, n, err, seed);
            cs.retain(|c| c.scan.len() >= 10);
            let n = cs.len();
            let mut times = vec![f64::INFINITY; n];
            let mut paths = vec![StartPath::Plain; n];
            let (mut ok, mut win) = (0, 0);
            for pass in 0..3 {
                for (k, c) in cs.iter().enumerate() {
                    if std::env::var("CASE").is_ok_and(|v| v != k.to_string()) {
                        continue;
                    }
                    if std::env::var("CASE").is_ok() {
                        eprintln!("truth {:?} initial {:?}", c.truth, c.initial);
                    }
                    let t0 = Instant::now();
                    let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
                    times[k] = times[k].min(t0.elapsed().as_secs_f64() * 1e3);
                    if pass > 0 {
                        continue;
                    }
                    paths[k] = r.start;
                    let dt = (r.pose.x - c.truth.x).hypot(r.pose.y - c.truth.y);
                    let dth = wrap_angle(r.pose.theta - c.truth.theta).abs();
                    let good = dt < 0.02 && dth < 0.5f64.to_radians();
                    ok += good as usize;
                    win += !matches!(r.start, StartPath::Plain | StartPath::Prior) as usize;
                    let verbose = std::env::var("VERBOSE").is_ok();
                    let paths = std::env::var("PATHS").is_ok();
                    if (!good && verbose) || paths {
                        let at_truth = icploc_core::icp::assess(&c.scan, &idx, c.truth, &cfg);
                        let plain_cfg = IcpConfig {
                            window_search: false,
                            ..cfg.clone()
                        };
                        let pl = align(&c.scan, &idx, c.initial, &plain_cfg).unwrap();
                        let pf = icploc_core::icp::assess(&c.scan, &idx, pl.pose, &cfg);
                        let pd = (pl.pose.x - c.truth.x).hypot(pl.pose.y - c.truth.y);
                        let pth = wrap_angle(pl.pose.theta - c.truth.theta).to_degrees();
                        eprintln!(
                            "  {} #{k} {:?} err ({:.3}, {:.3}, {:.2} deg) fit {} | truth {} | plain d {pd:.3} th {pth:.2} {:?} deg {:.3} fit {} | win {:?}/{:?}",
                            if good { "ok  " } else { "MISS" },
                            r.start,
                            r.pose.x - c.truth.x,
                            r.pose.y - c.truth.y,
                            wrap_angle(r.pose.theta - c.truth.theta).to_degrees(),
                            f(&r.fit.unwrap()),
                            f(&at_truth),
                            pl.termination,
                            pl.degeneracy,
                            f(&pf),
                            r.window_score,
                            r.window_second
                        );
                    }
                }
            }
            if std::env::var("TIMING").is_ok() {
                let plain_cfg = IcpConfig {
                    window_search: false,
                    ..cfg.clone()
                };
                let (mut tp, mut ta) = (Vec::new(), Vec::new());
                let mut iters = Vec::new();
                for c in &cs {
                    let t0 = Instant::now();
                    let r = align(&c.scan, &idx, c.initial, &plain_cfg).unwrap();
                    tp.push(t0.elapsed().as_secs_f64() * 1e3);
                    iters.push(r.iterations);
                    let t0 = Instant::now();
                    std::hint::black_box(icploc_core::icp::assess(&c.scan, &idx, r.pose, &cfg));
                    ta.push(t0.elapsed().as_secs_f64() * 1e3);
                }
                tp.sort_by(f64::total_cmp);
                ta.sort_by(f64::total_cmp);
                iters.sort();
                println!(
                    "{:9} {name}: plain ICP iterations median {} p95 {}, median {:.3} ms p95 {:.3}; assess median {:.3} ms",
                    w.name,
                    iters[n / 2],
                    iters[n * 95 / 100],
                    tp[n / 2],
                    tp[n * 95 / 100],
                    ta[n / 2]
                );
            }
            if std::env::var("CASE").is_ok() {
                continue;
            }
            if std::env::var("BYPATH").is_ok() {
                for p in [
                    StartPath::Plain,
                    StartPath::Prior,
                    StartPath::Local,
                    StartPath::Window,
                    StartPath::WindowKeptPlain,
                ] {
                    let mut t: Vec<f64> = (0..n)
                        .filter(|&k| paths[k] == p)
                        .map(|k| times[k])
                        .collect();
                    if t.is_empty() {
                        continue;
                    }
                    t.sort_by(f64::total_cmp);
                    println!(
                        "    {:?}: {} cases, median {:.3} ms, p95 {:.3} ms",
                        p,
                        t.len(),
                        t[t.len() / 2],
                        t[t.len() * 95 / 100]
                    );
                }
            }
            times.sort_by(f64::total_cmp);
            println!(
                "{:9} {name}: {ok}/{n} ok ({:.1} %), window ran {win}, median {:.3} ms, p95 {:.3} ms, max {:.3} ms (field build {:?})",
                w.name,
                100.0 * ok as f64 / n as f64,
                times[n / 2],
                times[n * 95 / 100],
                times[n - 1],
                build
            );
        }
    }
}
