//! Diagnostics (ignored test): classify failures of the default align on the families.
use super::*;
use crate::index::DEFAULT_CACHE_RESOLUTION;
use crate::testkit::{sample_segments, world_cases, worlds};
use std::time::Instant;

fn err(a: Pose2, b: Pose2) -> (f64, f64) {
    ((a.x - b.x).hypot(a.y - b.y), wrap_angle(a.theta - b.theta).to_degrees())
}

#[test]
#[ignore]
fn diag_families() {
    let cfg = IcpConfig { window_angle_step: 2f64.to_radians(), ..IcpConfig::default() };
    let quiet = std::env::var("QUIET").is_ok();
    for w in worlds() {
        let (p, n) = sample_segments(&w.map_segments(), 0.025);
        let idx = MapIndex::new(p, Some(n)).unwrap().with_cache(Some(DEFAULT_CACHE_RESOLUTION)).unwrap();
        let field = idx.likelihood_field().unwrap();
        for (name, e) in [("small", (0.3, 0.3, 10f64.to_radians())), ("large", (1.0, 0.5, 25f64.to_radians()))] {
            let cs = world_cases(&w, 200, e, 7);
            let (mut tp, mut ta, mut tw, mut tr) = (0.0, 0.0, 0.0, 0.0);
            let mut ws = Workspace::default();
            let mut nplainok_notexpl = 0;
            let mut times: Vec<f64> = Vec::new();
            let mut fails = 0;
            for (ci, c) in cs.iter().enumerate() {
                let t0 = Instant::now();
                let plain = align_plain(&c.scan, &idx, c.initial, &cfg, &mut ws);
                let t1 = Instant::now();
                let fit = assess(&c.scan, &idx, plain.pose, &cfg);
                let t2 = Instant::now();
                let win = window::search(field, &c.scan, c.initial, &cfg);
                let t3 = Instant::now();
                let mut r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
                let mut t4 = Instant::now();
                let mut best_t = t4 - t3;
                for _ in 0..4 {
                    let t5 = Instant::now();
                    r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
                    t4 = Instant::now();
                    best_t = best_t.min(t4 - t5);
                }
                tp += (t1 - t0).as_secs_f64();
                ta += (t2 - t1).as_secs_f64();
                tw += (t3 - t2).as_secs_f64();
                tr += (t4 - t3).as_secs_f64();
                times.push(best_t.as_secs_f64());
                let (pd, pa) = err(plain.pose, c.truth);
                let plain_ok = pd < 0.02 && pa.abs() < 0.5;
                if plain_ok && !(plain.converged && explains(&fit, &cfg)) {
                    nplainok_notexpl += 1;
                }
                let (d, a) = err(r.pose, c.truth);
                if d < 0.02 && a.abs() < 0.5 {
                    continue;
                }
                fails += 1;
                if quiet { continue; }
                let tr_r = align_plain(&c.scan, &idx, c.truth, &cfg, &mut ws);
                let tfit = assess(&c.scan, &idx, tr_r.pose, &cfg);
                let rfit = r.fit.unwrap_or(fit);
                eprintln!("{} {name} #{ci}: truth ({:.2},{:.2},{:.0}) got err {d:.3} m {a:.2}° path {:?}; plain err {pd:.3} {pa:.2} conv {} fit {:.2}/{:.3}/{:.2}/{:.3}; result fit {:.2}/{:.3}/{:.2} score {:.3}; truth-refined fit {:.2}/{:.3}/{:.2} score {:.3}",
                    w.name, c.truth.x, c.truth.y, c.truth.theta.to_degrees(), r.start, plain.converged,
                    fit.inlier_ratio, fit.rms, fit.see_through, fit.score,
                    rfit.inlier_ratio, rfit.rms, rfit.see_through, rfit.score,
                    tfit.inlier_ratio, tfit.rms, tfit.see_through, tfit.score);
                if let Some(win) = &win {
                    let s: Vec<String> = win.seeds.iter().take(12).map(|(q, s)| { let (d, a) = err(*q, c.truth); format!("{d:.2}m/{a:.0}°:{s:.2}") }).collect();
                    eprintln!("    seeds {}", s.join(" "));
                }
            }
            let n = cs.len() as f64;
            times.sort_by(f64::total_cmp);
            eprintln!("SUMMARY {} {name}: {} ok of {}, align median {:.0} µs p95 {:.0} µs", w.name, cs.len() - fails, cs.len(), times[times.len()/2]*1e6, times[times.len()*95/100]*1e6);
            eprintln!("{} {name}: mean plain {:.0} µs, assess {:.0} µs, window {:.0} µs, full align {:.0} µs; plain right but not accepted: {nplainok_notexpl}",
                w.name, tp / n * 1e6, ta / n * 1e6, tw / n * 1e6, tr / n * 1e6);
        }
    }
}

#[test]
#[ignore]
fn diag_accept_stats() {
    use std::io::Write;
    let cfg = IcpConfig::default();
    let mut f = std::fs::File::create("/tmp/core/accept.csv").unwrap();
    writeln!(f, "family,start,ok,conv,inl,rms,st,score,stall,dist").unwrap();
    for w in worlds() {
        let (p, n) = sample_segments(&w.map_segments(), 0.025);
        let idx = MapIndex::new(p, Some(n)).unwrap().with_cache(Some(DEFAULT_CACHE_RESOLUTION)).unwrap();
        for (name, e) in [("small", (0.3, 0.3, 10f64.to_radians())), ("large", (1.0, 0.5, 25f64.to_radians()))] {
            let cs = world_cases(&w, 400, e, 99);
            let mut ws = Workspace::default();
            for c in &cs {
                let plain = align_plain(&c.scan, &idx, c.initial, &cfg, &mut ws);
                let fit = assess(&c.scan, &idx, plain.pose, &cfg);
                let stall = see_through(&c.scan, &idx, plain.pose); // 48 beams anyway
                let (d, a) = err(plain.pose, c.truth);
                let ok = d < 0.02 && a.abs() < 0.5;
                writeln!(f, "{},{name},{},{},{:.4},{:.5},{:.4},{:.4},{:.4},{:.3}", w.name, ok as u8, plain.converged as u8, fit.inlier_ratio, fit.rms, fit.see_through, fit.score, stall, d).unwrap();
            }
        }
    }
}

fn min_time<T>(reps: usize, mut f: impl FnMut() -> T) -> (T, f64) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..reps {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    (out.unwrap(), best * 1e6)
}

#[test]
#[ignore]
fn diag_phases() {
    let cfg = IcpConfig { window_angle_step: 2f64.to_radians(), ..IcpConfig::default() };
    for w in worlds() {
        let (p, n) = sample_segments(&w.map_segments(), 0.025);
        let idx = MapIndex::new(p, Some(n)).unwrap().with_cache(Some(DEFAULT_CACHE_RESOLUTION)).unwrap();
        let field = idx.likelihood_field().unwrap();
        for (name, e) in [("small", (0.3, 0.3, 10f64.to_radians())), ("large", (1.0, 0.5, 25f64.to_radians()))] {
            let cs = world_cases(&w, 100, e, 7);
            let mut ws = Workspace::default();
            let mut acc = [0.0f64; 6];
            let mut its = 0usize;
            let mut nw = 0;
            for c in &cs {
                let (plain, t0) = min_time(3, || align_plain(&c.scan, &idx, c.initial, &cfg, &mut ws));
                its += plain.iterations;
                let (_fit, t1) = min_time(3, || assess(&c.scan, &idx, plain.pose, &cfg));
                let (win, t2) = min_time(3, || window::search(field, &c.scan, c.initial, &cfg));
                let Some(win) = win else { continue };
                nw += 1;
                let coarse_cfg = IcpConfig { expected_noise: cfg.expected_noise.max(0.5 * field.resolution() + 0.025), ..cfg.clone() };
                let sub = window::subsample(&c.scan, c.scan.len().div_ceil(window::RANKING_POINTS), 3);
                let (ranked, t3) = min_time(3, || {
                    let mut ranked: Vec<(f64, Pose2)> = win.seeds.iter().map(|&(seed, _)| (assess(&sub, &idx, seed, &coarse_cfg).score, seed)).collect();
                    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
                    ranked
                });
                let refine_cfg = IcpConfig { max_correspondence_distance: (4.0 * field.resolution()).clamp(cfg.min_correspondence_distance, cfg.max_correspondence_distance), ..cfg.clone() };
                let (_, t4) = min_time(3, || {
                    for &(_, seed) in ranked.iter().take(3) {
                        let r = align_plain(&c.scan, &idx, seed, &refine_cfg, &mut Workspace::default());
                        let _ = assess(&c.scan, &idx, r.pose, &cfg);
                    }
                });
                let (_, t5) = min_time(3, || see_through(&c.scan, &idx, c.truth));
                for (a, t) in acc.iter_mut().zip([t0, t1, t2, t3, t4, t5]) { *a += t; }
            }
            let n = cs.len() as f64;
            eprintln!("{} {name}: plain {:.0} µs ({:.1} it), assess {:.0}, bnb {:.0} (over {nw}), rank {:.0}, refine3 {:.0}, one see_through {:.0}", w.name, acc[0]/n, its as f64/n, acc[1]/n, acc[2]/nw as f64, acc[3]/nw as f64, acc[4]/nw as f64, acc[5]/n);
        }
    }
}
