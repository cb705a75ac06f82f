use icploc_core::se2::wrap_angle;
use icploc_core::testkit::{cases, office_segments, sample_segments};
use icploc_core::{align, IcpConfig, MapIndex, Metric};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let spacing: f64 = args.get(1).map(|s| s.parse().unwrap()).unwrap_or(0.05);
    let (p, n) = sample_segments(&office_segments(), spacing);
    let idx = MapIndex::new(p, Some(n)).unwrap();
    for err in [(0.3, 0.3, 10f64.to_radians()), (1.0, 0.5, 25f64.to_radians())] {
    let cs = cases(&office_segments(), 200, err, 0.01, 0.2, 7);
    for metric in [Metric::PointToPoint, Metric::PointToLine] {
        let cfg = IcpConfig { metric, ..IcpConfig::default() };
        let mut ok = 0; let mut its = 0; let mut conv = 0;
        let t0 = std::time::Instant::now();
        let mut terms = std::collections::BTreeMap::new();
        for c in &cs {
            let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
            let dt = ((r.pose.x - c.truth.x).powi(2) + (r.pose.y - c.truth.y).powi(2)).sqrt();
            let dth = wrap_angle(r.pose.theta - c.truth.theta).abs();
            if dt < 0.02 && dth < 0.5f64.to_radians() { ok += 1; }
            its += r.iterations; if r.converged { conv += 1; }
            *terms.entry(r.termination.as_str()).or_insert(0) += 1;
        }
        let el = t0.elapsed().as_secs_f64() / cs.len() as f64;
        println!("{err:?} {metric:?} n={} ok={ok}/{} conv={conv} mean_it={:.1} {:.1}us {terms:?}", idx.len(), cs.len(), its as f64 / cs.len() as f64, el * 1e6);
    }}
}
