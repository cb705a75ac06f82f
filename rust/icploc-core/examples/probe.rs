use icploc_core::se2::wrap_angle;
use icploc_core::testkit::{cases, office_segments, sample_segments};
use icploc_core::{align, IcpConfig, MapIndex, Metric};
fn main() {
    let a: Vec<f64> = std::env::args()
        .skip(1)
        .map(|s| s.parse().unwrap())
        .collect();
    let (spacing, maxd, mind, decay, p2l, big) = (a[0], a[1], a[2], a[3], a[4] > 0.5, a[5] > 0.5);
    let (p, n) = sample_segments(&office_segments(), spacing);
    let idx = MapIndex::new(p, Some(n))
        .unwrap()
        .with_cache(if a[6] > 0.0 { Some(a[6]) } else { None })
        .unwrap();
    let err = if big {
        (1.0, 0.5, 25f64.to_radians())
    } else {
        (0.3, 0.3, 10f64.to_radians())
    };
    let cs = cases(&office_segments(), 200, err, 0.01, 0.2, 7);
    let metric = if p2l {
        Metric::PointToLine
    } else {
        Metric::PointToPoint
    };
    let cfg = IcpConfig {
        metric,
        max_correspondence_distance: maxd,
        min_correspondence_distance: mind,
        threshold_decay: decay,
        heading_search: a[7].to_radians(),
        heading_step: a[8].to_radians(),
        ..IcpConfig::default()
    };
    for c in &cs {
        let _ = align(&c.scan, &idx, c.initial, &cfg);
    }
    let mut ok = 0;
    let mut its = 0;
    let mut times = vec![];
    let mut terms = std::collections::BTreeMap::new();
    for c in &cs {
        let t0 = std::time::Instant::now();
        let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
        times.push(t0.elapsed().as_secs_f64());
        let dt = ((r.pose.x - c.truth.x).powi(2) + (r.pose.y - c.truth.y).powi(2)).sqrt();
        let dth = wrap_angle(r.pose.theta - c.truth.theta).abs();
        if dt < 0.02 && dth < 0.5f64.to_radians() {
            ok += 1;
        }
        its += r.iterations;
        *terms.entry(r.termination.as_str()).or_insert(0) += 1;
    }
    times.sort_by(f64::total_cmp);
    println!(
        "{a:?} n={} ok={ok}/{} mean_it={:.1} med {:.1}us {terms:?}",
        idx.len(),
        cs.len(),
        its as f64 / cs.len() as f64,
        times[times.len() / 2] * 1e6
    );
}
