//! Success and timing of `align()` with the default config on the three families
//! (a quick table; `cargo bench` is the benchmark): `cargo run --release --example families [n]`.
use std::time::Instant;

use icploc_core::index::DEFAULT_CACHE_RESOLUTION;
use icploc_core::se2::wrap_angle;
use icploc_core::testkit::{sample_segments, world_cases, worlds};
use icploc_core::{align, IcpConfig, MapIndex, StartPath};

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(200);
    let cfg = IcpConfig::default();
    let only = std::env::var("ONLY").ok();
    for w in worlds() {
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
            let cs = world_cases(&w, n, err, 7);
            let mut times = Vec::new();
            let (mut ok, mut win) = (0, 0);
            for c in &cs {
                let t0 = Instant::now();
                let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
                times.push(t0.elapsed().as_secs_f64() * 1e3);
                let dt = (r.pose.x - c.truth.x).hypot(r.pose.y - c.truth.y);
                let dth = wrap_angle(r.pose.theta - c.truth.theta).abs();
                let good = dt < 0.02 && dth < 0.5f64.to_radians();
                ok += good as usize;
                win += (r.start != StartPath::Plain) as usize;
                if !good && std::env::var("VERBOSE").is_ok() {
                    let f = |x: &icploc_core::Fit| {
                        format!(
                            "{:.2}/{:.3}/{:.2}/{:.3}",
                            x.inlier_ratio, x.rms, x.see_through, x.score
                        )
                    };
                    let at_truth = icploc_core::icp::assess(&c.scan, &idx, c.truth, &cfg);
                    let plain_cfg = IcpConfig {
                        window_search: false,
                        ..cfg.clone()
                    };
                    let rt = align(&c.scan, &idx, c.truth, &plain_cfg).unwrap();
                    let at_refined = icploc_core::icp::assess(&c.scan, &idx, rt.pose, &cfg);
                    eprintln!(
                        "  miss {:?} err ({:.2}, {:.2}, {:.1} deg) fit {} | truth {} | refined-from-truth {} (d {:.3}) | win {:?}/{:?}",
                        r.start,
                        r.pose.x - c.truth.x,
                        r.pose.y - c.truth.y,
                        wrap_angle(r.pose.theta - c.truth.theta).to_degrees(),
                        f(&r.fit.unwrap()), f(&at_truth), f(&at_refined),
                        (rt.pose.x - c.truth.x).hypot(rt.pose.y - c.truth.y),
                        r.window_score, r.window_second
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
