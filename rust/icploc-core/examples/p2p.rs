use icploc_core::se2::wrap_angle;
use icploc_core::testkit::{cases, office_segments, sample_segments};
use icploc_core::{align, IcpConfig, MapIndex, Metric};
fn main() {
    let (p, n) = sample_segments(&office_segments(), 0.05);
    let idx = MapIndex::new(p, Some(n))
        .unwrap()
        .with_cache(Some(0.02))
        .unwrap();
    let cs = cases(
        &office_segments(),
        40,
        (0.3, 0.3, 10f64.to_radians()),
        0.01,
        0.2,
        11,
    );
    for (k, c) in cs.iter().enumerate() {
        let cfg = IcpConfig {
            metric: Metric::PointToPoint,
            ..IcpConfig::default()
        };
        let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
        let r2 = align(&c.scan, &idx, c.initial, &IcpConfig::default()).unwrap();
        let dt = ((r.pose.x - c.truth.x).powi(2) + (r.pose.y - c.truth.y).powi(2)).sqrt();
        let dth = wrap_angle(r.pose.theta - c.truth.theta).abs().to_degrees();
        let dt2 = ((r2.pose.x - c.truth.x).powi(2) + (r2.pose.y - c.truth.y).powi(2)).sqrt();
        println!(
            "{k}: p2p dt={dt:.4} dth={dth:.3} it={} {} inl={:.2} | p2l dt={dt2:.4} it={} deg={:.3}",
            r.iterations,
            r.termination.as_str(),
            r.inliers as f64 / r.num_points as f64,
            r2.iterations,
            r2.degeneracy
        );
    }
}
