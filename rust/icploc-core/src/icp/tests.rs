use super::*;
use crate::testkit::{cases, make_scan, office_segments, sample_segments, Rng};
use proptest::prelude::*;

fn scattered_map(seed: u64, n: usize) -> Vec<[f64; 2]> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| [rng.range(-5.0, 5.0), rng.range(-5.0, 5.0)])
        .collect()
}

fn office_index(spacing: f64) -> MapIndex {
    let (p, n) = sample_segments(&office_segments(), spacing);
    MapIndex::new(p, Some(n)).unwrap()
}

fn cfg(metric: Metric) -> IcpConfig {
    IcpConfig {
        metric,
        step_tolerance: 1e-12,
        mse_change: 0.0,
        mse_threshold: 0.0,
        max_iterations: 100,
        min_correspondence_distance: 0.5,
        max_correspondence_distance: 1.0,
        ..IcpConfig::default()
    }
}

/// The scan is the map seen from `truth`: exact correspondences exist.
fn exact_scan(map: &[[f64; 2]], truth: Pose2) -> Vec<[f64; 2]> {
    let inv = truth.inverse();
    map.iter().map(|p| inv.transform(*p)).collect()
}

/// The fit is the exact pose (to 1e-9 m and rad).
fn assert_exact(r: &IcpResult, truth: Pose2) {
    let ok = (r.pose.x - truth.x).abs() < 1e-9
        && (r.pose.y - truth.y).abs() < 1e-9
        && wrap_angle(r.pose.theta - truth.theta).abs() < 1e-9;
    assert!(ok, "{:?} vs {:?} ({:?})", r.pose, truth, r.fit);
}

#[test]
fn noise_free_is_recovered_exactly_both_metrics() {
    let map = scattered_map(1, 200);
    let idx = MapIndex::new(map.clone(), None).unwrap();
    let truth = Pose2::new(3.0, -2.0, 0.4);
    let scan = exact_scan(&map, truth);
    for metric in [Metric::PointToPoint, Metric::PointToLine] {
        let init = Pose2::new(3.02, -2.01, 0.405);
        let r = align(&scan, &idx, init, &cfg(metric)).unwrap();
        assert!(r.converged, "{metric:?} {:?}", r.termination);
        assert!((r.pose.x - truth.x).abs() < 1e-9, "{metric:?} {:?}", r.pose);
        assert!((r.pose.y - truth.y).abs() < 1e-9);
        assert!(wrap_angle(r.pose.theta - truth.theta).abs() < 1e-9);
        assert_eq!(r.inliers, 200);
        assert!(r.mse < 1e-18);
    }
}

#[test]
fn paper_rule_mse_below_tau_stops() {
    let map = scattered_map(2, 100);
    let idx = MapIndex::new(map.clone(), None).unwrap();
    let truth = Pose2::new(0.5, 0.5, 0.1);
    let scan = exact_scan(&map, truth);
    let mut c = IcpConfig::paper(0.5);
    c.mse_threshold = 1e-10;
    let r = align(&scan, &idx, Pose2::new(0.51, 0.5, 0.1), &c).unwrap();
    assert_eq!(r.termination, Termination::MseBelowThreshold);
    assert!(r.converged);
}

/// The coarse stages see a subsample of the scan; a call that stops in one (an iteration
/// limit) still reports the pairs of the whole scan at its final pose.
#[test]
fn an_iteration_limit_in_a_coarse_stage_reports_the_whole_scans_pairs() {
    let segs = office_segments();
    let idx = office_index(0.05);
    let c = &cases(&segs, 1, (0.2, 0.2, 0.05), 0.01, 0.2, 3)[0];
    let conf = IcpConfig {
        max_iterations: 2,
        window_search: false,
        ..IcpConfig::default()
    };
    let r = align(&c.scan, &idx, c.initial, &conf).unwrap();
    assert_eq!(r.termination, Termination::MaxIterations);
    // point-to-line takes one stage per iteration: the second iteration ran at stage 1,
    // a coarse one (its threshold above the final one)
    let thr = conf.threshold_at(1);
    assert!(thr > conf.min_correspondence_distance);
    let whole = c
        .scan
        .iter()
        .filter(|p| idx.correspondence(r.pose.transform(**p)).0 <= thr * thr)
        .count();
    assert_eq!(r.num_points, c.scan.len());
    assert_eq!(r.inliers, whole);
    // trimmed as every iteration is: the best 80 % of those pairs
    let trimmed = IcpConfig {
        trim_fraction: 0.8,
        ..conf.clone()
    };
    let t = align(&c.scan, &idx, c.initial, &trimmed).unwrap();
    assert_eq!(t.termination, Termination::MaxIterations);
    let whole_t = c
        .scan
        .iter()
        .filter(|p| idx.correspondence(t.pose.transform(**p)).0 <= thr * thr)
        .count();
    assert_eq!(t.inliers, (0.8 * whole_t as f64).ceil() as usize);
}

/// A coarse stage sees ~96 of the scan's points: it needs its share of `min_inlier_ratio`
/// (0.2 of a 720-beam scan: 144, more than the subsample holds),
/// not the whole scan's count (which it can never reach: the call used to stop at once,
/// `too_few_inliers`, with the pose unchanged).
#[test]
fn a_coarse_stage_needs_only_its_share_of_the_inliers() {
    let segs = office_segments();
    let idx = office_index(0.05);
    let c = &cases(&segs, 1, (0.2, 0.2, 0.05), 0.01, 0.0, 3)[0];
    // a 720-beam scan of the same place (a 0.25° laser): its subsample holds ~100 points
    let scan = make_scan(&segs, c.truth, 720, 30.0, 0.01, 0.0, &mut Rng::new(5));
    assert!(scan.len() >= 600, "a scan the coarse stages subsample");
    let conf = IcpConfig {
        min_inlier_ratio: 0.2,
        window_search: false,
        ..IcpConfig::default()
    };
    // plain ICP itself (align's verified start would retry a failed call from elsewhere)
    let r = align_plain(&scan, &idx, c.initial, &conf, &mut Workspace::default());
    assert!(
        r.converged,
        "{:?} after {} iterations",
        r.termination, r.iterations
    );
    let dt = ((r.pose.x - c.truth.x).powi(2) + (r.pose.y - c.truth.y).powi(2)).sqrt();
    assert!(dt < 0.02, "{:?} vs {:?}", r.pose, c.truth);
}

#[test]
fn iteration_limit_is_not_convergence() {
    let idx = office_index(0.05);
    let case = &cases(&office_segments(), 1, (0.3, 0.3, 0.17), 0.01, 0.2, 5)[0];
    let c = IcpConfig {
        max_iterations: 1,
        ..IcpConfig::default()
    };
    let r = align(&case.scan, &idx, case.initial, &c).unwrap();
    assert!(!r.converged);
    assert_eq!(r.termination, Termination::MaxIterations);
    assert_eq!(r.iterations, 1);
}

#[test]
fn too_few_inliers_is_not_convergence_and_not_identity() {
    let idx = office_index(0.05);
    let case = &cases(&office_segments(), 1, (0.0, 0.0, 0.0), 0.01, 0.0, 6)[0];
    // start 100 m away: nothing within the threshold
    let init = Pose2::new(case.truth.x + 100.0, case.truth.y, case.truth.theta);
    let r = align(&case.scan, &idx, init, &IcpConfig::default()).unwrap();
    assert!(!r.converged);
    assert_eq!(r.termination, Termination::TooFewInliers);
    assert_eq!(r.pose, init);
}

#[test]
fn office_accuracy_small_start_error() {
    // 361-beam scans, 1 cm noise, 20% of beams on unmapped obstacles, start error
    // (0.3 m, 0.3 m, 10°). Point-to-line: within 2 cm and 0.5°. Point-to-point converges
    // slowly along walls (sampled at 5 cm): within 5 cm and 1°.
    let segs = office_segments();
    let idx = office_index(0.05).with_cache(Some(0.02)).unwrap();
    let cs = cases(&segs, 40, (0.3, 0.3, 10f64.to_radians()), 0.01, 0.2, 11);
    for (metric, tol_t, tol_r, need) in [
        (Metric::PointToLine, 0.02, 0.5f64, 37),
        (Metric::PointToPoint, 0.05, 1.0f64, 32),
    ] {
        let c = IcpConfig {
            metric,
            ..IcpConfig::default()
        };
        let ok = cs
            .iter()
            .filter(|k| {
                let r = align(&k.scan, &idx, k.initial, &c).unwrap();
                let dt = ((r.pose.x - k.truth.x).powi(2) + (r.pose.y - k.truth.y).powi(2)).sqrt();
                let dth = wrap_angle(r.pose.theta - k.truth.theta).abs();
                dt < tol_t && dth < tol_r.to_radians()
            })
            .count();
        assert!(ok >= need, "{metric:?}: {ok}/40");
    }
}

#[test]
fn heading_search_rescues_large_start_errors() {
    let segs = office_segments();
    let idx = office_index(0.05).with_cache(Some(0.02)).unwrap();
    let cs = cases(&segs, 40, (1.0, 0.5, 25f64.to_radians()), 0.01, 0.2, 12);
    let count = |c: &IcpConfig| {
        cs.iter()
            .filter(|k| {
                let r = align(&k.scan, &idx, k.initial, c).unwrap();
                let dt = ((r.pose.x - k.truth.x).powi(2) + (r.pose.y - k.truth.y).powi(2)).sqrt();
                dt < 0.02 && wrap_angle(r.pose.theta - k.truth.theta).abs() < 0.5f64.to_radians()
            })
            .count()
    };
    // the heading search on its own (the verified start's window search off), unweighted
    // as it was tuned (with Huber weights it rescues 31 of 40, not 36)
    let base = IcpConfig {
        window_search: false,
        robust: Robust::None,
        ..IcpConfig::default()
    };
    let plain = count(&base);
    let searched = count(&IcpConfig {
        heading_search: 30f64.to_radians(),
        heading_step: 10f64.to_radians(),
        ..base.clone()
    });
    assert!(searched >= 36, "{searched}/40");
    assert!(searched > plain, "{searched} vs {plain}");
    let with_position = count(&IcpConfig {
        heading_search: 30f64.to_radians(),
        heading_step: 10f64.to_radians(),
        position_search: 0.5,
        ..base.clone()
    });
    assert!(with_position >= searched, "{with_position} vs {searched}");
}

#[test]
fn corridor_is_degenerate_room_is_not() {
    // two long parallel walls
    let segs = vec![[-50.0, -1.0, 50.0, -1.0], [-50.0, 1.0, 50.0, 1.0]];
    let (p, n) = sample_segments(&segs, 0.05);
    let idx = MapIndex::new(p, Some(n)).unwrap();
    let mut rng = Rng::new(3);
    let scan = crate::testkit::make_scan(&segs, Pose2::identity(), 361, 10.0, 0.0, 0.0, &mut rng);
    let r = align(
        &scan,
        &idx,
        Pose2::new(0.0, 0.05, 0.01),
        &IcpConfig::default(),
    )
    .unwrap();
    assert!(r.degeneracy < 1e-3, "{}", r.degeneracy);
    assert!(r.degenerate_direction[0].abs() > 0.99);
    assert!(r.covariance[0][0] > 1e3 * r.covariance[1][1]);
    assert!(r.pose.y.abs() < 1e-6);

    let idx = office_index(0.05);
    let c = &cases(&office_segments(), 1, (0.1, 0.1, 0.05), 0.01, 0.0, 8)[0];
    let r = align(&c.scan, &idx, c.initial, &IcpConfig::default()).unwrap();
    assert!(r.degeneracy > 0.05, "{}", r.degeneracy);
    for i in 0..3 {
        assert!(r.covariance[i][i] > 0.0 && r.covariance[i][i] < 1e-3);
    }
}

#[test]
fn trimmed_and_robust_variants_work() {
    let segs = office_segments();
    let idx = office_index(0.05);
    let cs = cases(&segs, 10, (0.2, 0.2, 0.1), 0.01, 0.3, 21);
    for (trim, robust) in [
        (0.7, Robust::None),
        (1.0, Robust::Huber),
        (1.0, Robust::Cauchy),
    ] {
        let c = IcpConfig {
            trim_fraction: trim,
            robust,
            ..IcpConfig::default()
        };
        let ok = cs
            .iter()
            .filter(|k| {
                let r = align(&k.scan, &idx, k.initial, &c).unwrap();
                ((r.pose.x - k.truth.x).powi(2) + (r.pose.y - k.truth.y).powi(2)).sqrt() < 0.03
            })
            .count();
        assert!(ok >= 9, "{trim} {robust:?}: {ok}");
    }
}

#[test]
fn config_validation_names_the_field() {
    let cases: Vec<(IcpConfig, &str)> = vec![
        (
            IcpConfig {
                prior_sure_rms: -0.5,
                ..Default::default()
            },
            "prior_sure_rms",
        ),
        (
            IcpConfig {
                prior_sure_rms: f64::NAN,
                ..Default::default()
            },
            "prior_sure_rms",
        ),
        (
            IcpConfig {
                max_iterations: 0,
                ..Default::default()
            },
            "max_iterations",
        ),
        (
            IcpConfig {
                max_correspondence_distance: 0.0,
                ..Default::default()
            },
            "max_correspondence_distance",
        ),
        (
            IcpConfig {
                max_correspondence_distance: f64::NAN,
                ..Default::default()
            },
            "max_correspondence_distance",
        ),
        (
            IcpConfig {
                min_correspondence_distance: -1.0,
                ..Default::default()
            },
            "min_correspondence_distance",
        ),
        (
            IcpConfig {
                min_correspondence_distance: 5.0,
                ..Default::default()
            },
            "min_correspondence_distance",
        ),
        (
            IcpConfig {
                threshold_decay: 0.0,
                ..Default::default()
            },
            "threshold_decay",
        ),
        (
            IcpConfig {
                trim_fraction: 1.5,
                ..Default::default()
            },
            "trim_fraction",
        ),
        (
            IcpConfig {
                robust_scale: 0.0,
                ..Default::default()
            },
            "robust_scale",
        ),
        (
            IcpConfig {
                min_inliers: 2,
                ..Default::default()
            },
            "min_inliers",
        ),
        (
            IcpConfig {
                min_inlier_ratio: 2.0,
                ..Default::default()
            },
            "min_inlier_ratio",
        ),
        (
            IcpConfig {
                mse_threshold: f64::INFINITY,
                ..Default::default()
            },
            "mse_threshold",
        ),
    ];
    for (c, field) in cases {
        match c.validate() {
            Err(IcpError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
            other => panic!("{field}: {other:?}"),
        }
    }
    IcpConfig::default().validate().unwrap();
}

#[test]
fn bad_inputs_are_errors() {
    let idx = office_index(0.5);
    let c = IcpConfig::default();
    let e = align(&[[0.0, 0.0]; 5], &idx, Pose2::identity(), &c).unwrap_err();
    assert!(matches!(
        e,
        IcpError::TooFewPoints {
            got: 5,
            min: 10,
            ..
        }
    ));
    let mut scan = vec![[1.0, 1.0]; 20];
    scan[7][1] = f64::NAN;
    assert!(matches!(
        align(&scan, &idx, Pose2::identity(), &c).unwrap_err(),
        IcpError::NonFinite { row: 7, .. }
    ));
    let scan = vec![[1.0, 1.0]; 20];
    assert!(matches!(
        align(&scan, &idx, Pose2::new(0.0, f64::INFINITY, 0.0), &c).unwrap_err(),
        IcpError::InvalidInput { .. }
    ));
}

#[test]
fn batch_matches_single_and_broadcasts() {
    let segs = office_segments();
    let idx = office_index(0.05);
    let cs = cases(&segs, 8, (0.3, 0.3, 0.17), 0.01, 0.2, 31);
    let c = IcpConfig::default();
    let scans: Vec<&[[f64; 2]]> = cs.iter().map(|k| k.scan.as_slice()).collect();
    let poses: Vec<Pose2> = cs.iter().map(|k| k.initial).collect();
    let batch = align_batch(&scans, &idx, &poses, &c, Some(2)).unwrap();
    for (k, r) in cs.iter().zip(&batch) {
        let single = align(&k.scan, &idx, k.initial, &c).unwrap();
        assert_eq!(r.as_ref().unwrap(), &single);
    }
    let multi = align_batch(&scans[..1], &idx, &poses, &c, None).unwrap();
    assert_eq!(multi.len(), 8);
    assert!(align_batch(&scans[..2], &idx, &poses, &c, None).is_err());
    assert!(align_batch(&scans, &idx, &poses, &c, Some(0)).is_err());
}

/// Regression (found by `prop_rigid_transform_recovered`): on scattered points 0.4 m
/// apart every beam passes within half a spacing of some isolated point, so the exact fit
/// has nearly all of its beams "through walls"; a window pose explaining a fifth of the
/// scan must not replace it.
#[test]
fn an_exact_fit_is_not_replaced_by_a_window_pose_explaining_less() {
    let map = scattered_map(847, 150);
    let idx = MapIndex::new(map.clone(), None).unwrap();
    let truth = Pose2::new(-3.825005148747359, -5.314194617441751, -0.3464690300748977);
    let scan = exact_scan(&map, truth);
    let init = Pose2::new(truth.x + 0.0093, truth.y, truth.theta);
    let r = align(&scan, &idx, init, &cfg(Metric::PointToPoint)).unwrap();
    assert_exact(&r, truth);
}

/// Regression (found by `prop_rigid_transform_recovered`): a sensor 70 m from a small map,
/// outside its bounds, where the plain point-to-line ICP from 0.01 rad off runs out of
/// iterations 9 m away; the window around the start lies outside the likelihood grid,
/// and its poses must still count (their clearance is at least the distance to the grid).
#[test]
fn window_poses_outside_the_maps_bounds_are_searched() {
    let map = scattered_map(210, 150);
    let idx = MapIndex::new(map.clone(), None).unwrap();
    let truth = Pose2::new(49.81322314579517, 49.342899726035014, 0.0);
    let scan = exact_scan(&map, truth);
    let init = Pose2::new(truth.x, truth.y, -0.009927417612509658);
    let r = align(&scan, &idx, init, &cfg(Metric::PointToLine)).unwrap();
    assert_exact(&r, truth);
}

/// Regression (found by `prop_rigid_transform_recovered`): a scan taken 70 m from a small
/// map; the point-to-line step's damping must not hold the translation back (a damping
/// scaled by the trace, which the rotation's r² terms dominate, stopped 1.3e-9 m off).
#[test]
fn point_to_line_from_far_away_converges_to_the_exact_pose() {
    let map = scattered_map(221, 150);
    let idx = MapIndex::new(map.clone(), None).unwrap();
    let truth = Pose2::new(-49.64238763425559, -47.014466987019915, 0.0);
    let scan = exact_scan(&map, truth);
    let init = Pose2::new(truth.x, truth.y - 0.0259318106262427, -0.00828622596042658);
    let r = align(&scan, &idx, init, &cfg(Metric::PointToLine)).unwrap();
    assert_exact(&r, truth);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, .. ProptestConfig::default() })]

    /// Random rigid transforms of noise-free scans are recovered to 1e-9.
    #[test]
    fn prop_rigid_transform_recovered(x in -50.0f64..50.0, y in -50.0f64..50.0,
                                      th in -std::f64::consts::PI..std::f64::consts::PI, seed in 0u64..1000,
                                      dx in -0.03f64..0.03, dy in -0.03f64..0.03, dth in -0.01f64..0.01,
                                      p2l in any::<bool>()) {
        let map = scattered_map(seed, 150);
        let idx = MapIndex::new(map.clone(), None).unwrap();
        let truth = Pose2::new(x, y, th);
        let scan = exact_scan(&map, truth);
        let metric = if p2l { Metric::PointToLine } else { Metric::PointToPoint };
        let r = align(&scan, &idx, Pose2::new(x + dx, y + dy, th + dth), &cfg(metric)).unwrap();
        prop_assert!((r.pose.x - x).abs() < 1e-9);
        prop_assert!((r.pose.y - y).abs() < 1e-9);
        prop_assert!(wrap_angle(r.pose.theta - th).abs() < 1e-9);
    }

    /// The answer does not depend on the order of the scan points.
    #[test]
    fn prop_order_independent(seed in 0u64..1000, shift in 1usize..300) {
        let segs = office_segments();
        let idx = office_index(0.1);
        let c = &cases(&segs, 1, (0.2, 0.2, 0.1), 0.01, 0.2, seed)[0];
        let mut rev = c.scan.clone();
        rev.reverse();
        let k = shift % rev.len();
        rev.rotate_left(k);
        for metric in [Metric::PointToPoint, Metric::PointToLine] {
            let conf = IcpConfig { metric, ..IcpConfig::default() };
            let a = align(&c.scan, &idx, c.initial, &conf).unwrap();
            let b = align(&rev, &idx, c.initial, &conf).unwrap();
            prop_assert!((a.pose.x - b.pose.x).abs() < 1e-9);
            prop_assert!((a.pose.y - b.pose.y).abs() < 1e-9);
            prop_assert!(wrap_angle(a.pose.theta - b.pose.theta).abs() < 1e-9);
            prop_assert_eq!(a.inliers, b.inliers);
        }
    }

    /// The rotation is always a yaw: the quaternion has no in-plane axis part.
    #[test]
    fn prop_rotation_is_yaw(pts in proptest::collection::vec((-10.0f64..10.0, -10.0f64..10.0, -10.0f64..10.0, -10.0f64..10.0), 3..40)) {
        let mut cc = CrossCovariance::default();
        for (a, b, c, d) in pts {
            cc.add([a, b], [c, d], 1.0);
        }
        if let Some(r) = cc.solve() {
            prop_assert_eq!(r.quaternion[1], 0.0);
            prop_assert_eq!(r.quaternion[2], 0.0);
            prop_assert!(r.theta.is_finite());
            prop_assert!((r.quaternion[0].powi(2) + r.quaternion[3].powi(2) - 1.0).abs() < 1e-9);
        }
    }

    /// No input, finite or not, makes the core panic, through the closest-point grid ICP
    /// uses by default (random resolutions included); a map is accepted exactly when it is
    /// non-empty, finite and within ±MAX_MAP_COORDINATE.
    #[test]
    fn prop_no_panic(scan in proptest::collection::vec((any::<f64>(), any::<f64>()), 0..40),
                     pose in (any::<f64>(), any::<f64>(), any::<f64>()),
                     thr in any::<f64>(),
                     map in prop_oneof![
                         proptest::collection::vec((any::<f64>(), any::<f64>()), 0..30),
                         proptest::collection::vec((-1e9f64..1e9, -1e9f64..1e9), 1..30),
                         proptest::collection::vec((-3.0f64..3.0, -3.0f64..3.0), 1..30),
                         (any::<f64>(), any::<f64>(), 1usize..30).prop_map(|(a, b, n)| vec![(a, b); n]),
                     ],
                     res in prop_oneof![Just(crate::index::DEFAULT_CACHE_RESOLUTION), any::<f64>(), 1e-5f64..10.0]) {
        use crate::index::MAX_MAP_COORDINATE;
        let scan: Vec<[f64; 2]> = scan.into_iter().map(|(a, b)| [a, b]).collect();
        let map: Vec<[f64; 2]> = map.into_iter().map(|(a, b)| [a, b]).collect();
        let valid = !map.is_empty()
            && map.iter().all(|p| p[0].abs() <= MAX_MAP_COORDINATE && p[1].abs() <= MAX_MAP_COORDINATE);
        let c = IcpConfig { max_correspondence_distance: thr, min_correspondence_distance: thr.abs().min(1.0), min_inliers: 3, ..IcpConfig::default() };
        let built = MapIndex::new(map, None);
        prop_assert_eq!(built.is_ok(), valid);
        if let Ok(idx) = built {
            let cached = idx.with_cache(Some(res));
            // exactly the positive finite resolutions (and 0: no grid) are accepted
            prop_assert_eq!(cached.is_ok(), res == 0.0 || (res > 0.0 && res.is_finite()));
            if let Ok(idx) = cached {
                let (_, j) = idx.correspondence([pose.0, pose.1]);
                prop_assert!(j < idx.len());
                let _ = align(&scan, &idx, Pose2::new(pose.0, pose.1, pose.2), &c);
                let _ = align(&scan, &idx, Pose2::new(pose.0, pose.1, pose.2), &IcpConfig::default());
                let _ = idx.visible(Pose2::new(pose.0, pose.1, pose.2), thr, thr, None, 0.05, 0.01);
                let _ = idx.within([pose.0, pose.1], thr);
            }
        }
        let _ = crate::raycast::raycast(&[[pose.0, pose.1, pose.2, thr]], Pose2::new(pose.0, 0.0, 0.0), &[thr], 10.0);
    }

    /// Finite but extreme scans against a map through the closest-point grid: every call
    /// returns a finite pose. At scale 1 the scan is the map (identity recovered); at
    /// 1e9 and beyond no scan point is within the 1e6 m correspondence distance, so the
    /// start pose comes back with too few inliers.
    #[test]
    fn prop_finite_extremes(scale in prop_oneof![Just(1e-300), Just(1e-9), Just(1.0), Just(1e9), Just(1e150), Just(1e300)], seed in 0u64..100) {
        let map = scattered_map(seed, 50);
        let idx = MapIndex::new(map.clone(), None).unwrap()
            .with_cache(Some(crate::index::DEFAULT_CACHE_RESOLUTION)).unwrap();
        prop_assert_eq!(idx.cache_resolution(), Some(crate::index::DEFAULT_CACHE_RESOLUTION));
        let scan: Vec<[f64; 2]> = map.iter().map(|p| [p[0] * scale, p[1] * scale]).collect();
        for metric in [Metric::PointToPoint, Metric::PointToLine] {
            let c = IcpConfig { metric, max_correspondence_distance: 1e6, min_correspondence_distance: 1e6, ..IcpConfig::default() };
            let r = align(&scan, &idx, Pose2::identity(), &c);
            prop_assert!(r.is_ok(), "{:?}", r);
            let r = r.unwrap();
            prop_assert!(r.pose.x.is_finite() && r.pose.y.is_finite() && r.pose.theta.is_finite(), "{:?}", r.pose);
            if scale == 1.0 {
                prop_assert!(r.pose.x.abs() < 1e-9 && r.pose.y.abs() < 1e-9 && r.pose.theta.abs() < 1e-9, "{:?}", r.pose);
            } else if scale >= 1e9 {
                prop_assert_eq!(r.termination, Termination::TooFewInliers);
                prop_assert_eq!(r.inliers, 0);
                prop_assert_eq!(r.pose, Pose2::identity());
            }
        }
    }
}

fn fit(inlier_ratio: f64, rms: f64, score: f64) -> Fit {
    Fit {
        inlier_ratio,
        rms,
        see_through: 0.0,
        vanished: 0.0,
        score,
    }
}

#[test]
fn a_loose_fit_ranks_below_a_tight_one_that_scores_a_little_less() {
    // the clinic's pattern: a wrong pose explains more points (0.68) at an RMS of 0.9 σ,
    // the truth fewer (0.59) at 0.42 σ
    let cfg = IcpConfig::default();
    let wrong = fit(0.88, 0.9 * cfg.expected_noise, 0.68);
    let truth = fit(0.63, 0.42 * cfg.expected_noise, 0.59);
    assert!(rank(&truth, &cfg) > rank(&wrong, &cfg));
}

#[test]
fn ranks_of_tight_fits_are_their_scores() {
    let cfg = IcpConfig::default();
    let f = fit(0.8, 0.3 * cfg.expected_noise, 0.7);
    assert_eq!(rank(&f, &cfg), 0.7);
}

#[test]
fn a_fit_beyond_the_window_does_not_explain_the_scan() {
    // a right fit in a room explains the scan from a start 10° off; the same fit seen from
    // a start 40° off lies outside the ±30° window (ICP turned that far: a symmetry)
    let segs = crate::testkit::rectangle(8.0, 5.0);
    let (p, n) = sample_segments(&segs, 0.025);
    let idx = MapIndex::new(p, Some(n)).unwrap();
    let truth = Pose2::new(3.0, 2.0, 0.2);
    let mut rng = Rng::new(8);
    let scan = crate::testkit::make_scan(&segs, truth, 361, 30.0, 0.005, 0.0, &mut rng);
    let cfg = IcpConfig::default();
    let r = align(&scan, &idx, truth, &cfg).unwrap();
    let f = r.fit.unwrap();
    let near = Pose2::new(3.0, 2.0, 0.2 + 10f64.to_radians());
    let far = Pose2::new(3.0, 2.0, 0.2 + 40f64.to_radians());
    assert_eq!(
        (
            acceptable(&r, &f, near, &cfg),
            acceptable(&r, &f, far, &cfg)
        ),
        (true, false)
    );
}

#[test]
fn places_along_a_corridor_only_replace_the_fit_when_right() {
    // the clinic and the warehouse from the small start: every result taken from a place
    // along the corridor (`local`) is right
    let mut local = 0;
    let mut wrong = Vec::new();
    for w in [
        crate::testkit::clinic_world(),
        crate::testkit::warehouse_world(),
    ] {
        let (p, n) = sample_segments(&w.map_segments(), 0.025);
        let idx = MapIndex::new(p, Some(n))
            .unwrap()
            .with_cache(Some(crate::index::DEFAULT_CACHE_RESOLUTION))
            .unwrap();
        for c in crate::testkit::world_cases(&w, 60, (0.3, 0.3, 10f64.to_radians()), 7) {
            let r = align(&c.scan, &idx, c.initial, &IcpConfig::default()).unwrap();
            if r.start == StartPath::Local {
                local += 1;
                let d = (r.pose.x - c.truth.x).hypot(r.pose.y - c.truth.y);
                if d >= 0.02
                    || wrap_angle(r.pose.theta - c.truth.theta).abs() >= 0.5f64.to_radians()
                {
                    wrong.push((w.name, d));
                }
            }
        }
    }
    eprintln!("{local} local results");
    assert_eq!(wrong, Vec::<(&str, f64)>::new());
}

#[test]
fn starts_turned_by_the_heading_prior_are_right_and_skip_the_window() {
    // warehouse, small starts (up to 10°): the fits from the heading prior that end the
    // search (`prior`) are all right, ran no window, and are common (plain ICP from 10°
    // off keeps the error among the racks)
    let w = crate::testkit::warehouse_world();
    let (p, n) = sample_segments(&w.map_segments(), 0.025);
    let idx = MapIndex::new(p, Some(n))
        .unwrap()
        .with_cache(Some(crate::index::DEFAULT_CACHE_RESOLUTION))
        .unwrap();
    let cs = crate::testkit::world_cases(&w, 60, (0.3, 0.3, 10f64.to_radians()), 9);
    let mut prior = 0;
    let mut wrong = Vec::new();
    for (k, c) in cs.iter().enumerate() {
        let r = align(&c.scan, &idx, c.initial, &IcpConfig::default()).unwrap();
        if r.start == StartPath::Prior {
            prior += 1;
            let d = (r.pose.x - c.truth.x).hypot(r.pose.y - c.truth.y);
            let dth = wrap_angle(r.pose.theta - c.truth.theta).abs();
            if d >= 0.02 || dth >= 0.5f64.to_radians() || r.window_score.is_some() {
                wrong.push((k, d, dth));
            }
        }
    }
    assert_eq!(
        (wrong, prior >= 15),
        (Vec::new(), true),
        "{prior} of 60 from the prior"
    );
}

fn clinic_index() -> (crate::testkit::World, MapIndex) {
    world_index(crate::testkit::clinic_world())
}

/// `w` with its map index as the bench builds it: 2.5 cm samples with exact normals, the
/// closest-point grid at the default resolution.
fn world_index(w: crate::testkit::World) -> (crate::testkit::World, MapIndex) {
    let (p, n) = sample_segments(&w.map_segments(), 0.025);
    let idx = MapIndex::new(p, Some(n))
        .unwrap()
        .with_cache(Some(crate::index::DEFAULT_CACHE_RESOLUTION))
        .unwrap();
    (w, idx)
}

#[test]
fn a_corridor_place_beyond_the_window_edge_is_found_by_its_door_jambs() {
    // the bench's clinic, large start (1 m, 0.5 m, 25°), seed 7, case 71: the truth lies at
    // the window's edge along the corridor; the narrow window's best is a place 1.28 m
    // along it, and the look along the corridor on an even subsample of the scan scores
    // every place within 0.2 %: the points off the corridor's walls tell them apart
    assert_clinic_case_succeeds((1.0, 0.5, 25f64.to_radians()), 71);
}

/// The bench's clinic case `case` (seed 7) from the start error `start`: the default
/// call ends within 2 cm and 0.5° of the truth.
fn assert_clinic_case_succeeds(start: (f64, f64, f64), case: usize) {
    let (w, idx) = clinic_index();
    let cs = crate::testkit::world_cases(&w, 200, start, 7);
    let c = &cs[case];
    let r = align(&c.scan, &idx, c.initial, &IcpConfig::default()).unwrap();
    let d = (r.pose.x - c.truth.x).hypot(r.pose.y - c.truth.y);
    let dth = wrap_angle(r.pose.theta - c.truth.theta).abs();
    assert!(
        d < 0.02 && dth < 0.5f64.to_radians(),
        "{d} m, {dth} rad, {:?}",
        r.start
    );
}

#[test]
fn the_heading_prior_sees_walls_within_two_metres() {
    // in the clinic's 3-4 m rooms most walls are within 2 m: four beam steps there are
    // chords of 3-7 cm, too short for a wall piece; the longer spans give the prior, and it
    // is within 1.5° of the truth's heading in most rooms
    let (w, idx) = clinic_index();
    let cs = crate::testkit::world_cases(&w, 60, (0.3, 0.3, 10f64.to_radians()), 3);
    let (mut some, mut close) = (0, 0);
    for c in &cs {
        let Some(h) = local::scan_directions(&c.scan) else {
            continue;
        };
        some += 1;
        let th = local::heading_prior(&h, idx.line_directions(), c.initial.theta, 0.5)
            .expect("walls correlate");
        close += (wrap_angle(th - c.truth.theta).abs() < 1.5f64.to_radians()) as usize;
    }
    assert!(
        some >= 57 && close >= 50,
        "{some} priors, {close} within 1.5°"
    );
}

#[test]
fn point_to_line_step_tolerance_caps_at_a_millimetre() {
    // the documented stop: point-to-line stops at a step below √`step_tolerance`, at most
    // `QUADRATIC_STOP` (1 mm / 1 mrad): any tolerance from 1e-6 up gives the same fit, and
    // only a smaller one (√ below 1 mm) asks for more iterations
    let segs = office_segments();
    let (p, n) = sample_segments(&segs, 0.025);
    let idx = MapIndex::new(p, Some(n)).unwrap();
    let cs = cases(&segs, 10, (0.1, 0.1, 0.05), 0.01, 0.0, 4);
    let run = |tol: f64| -> Vec<IcpResult> {
        let c = IcpConfig {
            step_tolerance: tol,
            window_search: false,
            ..IcpConfig::default()
        };
        cs.iter()
            .map(|k| align(&k.scan, &idx, k.initial, &c).unwrap())
            .collect()
    };
    let (a, b, tight) = (run(1e-6), run(1.0), run(1e-14));
    assert_eq!(a, b);
    let its = |v: &[IcpResult]| v.iter().map(|r| r.iterations).sum::<usize>();
    assert!(its(&tight) > its(&a), "{} vs {}", its(&tight), its(&a));
}

#[test]
fn the_fit_from_the_icps_own_closest_points_is_the_fresh_fit() {
    // the verified start scores a converged ICP from the closest points of its last pass
    // (no look-up per point): on every family the same fit as a fresh `assess` at the
    // final pose (the same inliers but for a point, RMS and score to a hair)
    let cfg = IcpConfig::default();
    let mut total = 0usize;
    for (w, idx) in family_indexes() {
        let cs = crate::testkit::world_cases(&w, 15, (0.3, 0.3, 10f64.to_radians()), 3);
        for c in &cs {
            let mut ws = Workspace::default();
            let r = align_plain(&c.scan, &idx, c.initial, &cfg, &mut ws);
            let fresh = assess(&c.scan, &idx, r.pose, &cfg);
            let got = assessed(&c.scan, &idx, &r, &cfg, &mut ws);
            total += 1;
            let one = 1.0 / c.scan.len() as f64 + 1e-12;
            assert!(
                (got.inlier_ratio - fresh.inlier_ratio).abs() <= one
                    && (got.rms - fresh.rms).abs() <= 2e-4
                    && (got.score - fresh.score).abs() <= 2e-3
                    && got.see_through == fresh.see_through,
                "{}: {got:?} vs {fresh:?}",
                w.name
            );
            // and exactly the stored pass's answer at that pass's pose
            if let Some(p) = ws.nn_pose {
                ws.resolve_nn(&idx);
                let at = window::assess_with(&c.scan, &idx, p, &cfg, &ws.nn);
                let exact = assess(&c.scan, &idx, p, &cfg);
                assert!(
                    (at.inlier_ratio - exact.inlier_ratio).abs() < 1e-12
                        && (at.score - exact.score).abs() < 1e-9,
                    "{}: {at:?} vs {exact:?}",
                    w.name
                );
            }
        }
    }
    // the reuse is what most calls take
    let taken = {
        let w = crate::testkit::office_world();
        let (p, n) = sample_segments(&w.map_segments(), 0.025);
        let idx = MapIndex::new(p, Some(n)).unwrap();
        let cs = crate::testkit::world_cases(&w, 20, (0.3, 0.3, 10f64.to_radians()), 5);
        cs.iter()
            .filter(|c| {
                let mut ws = Workspace::default();
                let r = align_plain(&c.scan, &idx, c.initial, &cfg, &mut ws);
                ws.nn_pose.is_some_and(|p| {
                    (r.pose.x - p.x).hypot(r.pose.y - p.y)
                        + wrap_angle(r.pose.theta - p.theta).abs() * ws.reach
                        <= window::REUSE_SHIFT
                })
            })
            .count()
    };
    assert!(taken >= 15, "the reuse ran on {taken} of 20 office calls");
    assert!(total >= 75);
}

#[test]
fn the_garage_scans_see_through_cars_that_left_and_hit_cars_that_came() {
    let w = crate::testkit::garage_world();
    // the layout of `benches/scenario.py`'s garage_world (the same SplitMix draws): 278
    // opaque segments, one glass door, 9 cars gone, 7 come
    assert_eq!(
        (
            w.opaque.len(),
            w.glass.len(),
            w.gone.len(),
            w.unmapped.len()
        ),
        (278, 1, 36, 28)
    );
    // every mapped segment is in the map; the unmapped ones are not
    let map = w.map_segments();
    assert!(w.gone.iter().all(|g| map.contains(g)));
    assert!(w.unmapped.iter().all(|u| !map.contains(u)));
    // a scan from an aisle facing the south row: some beams end where only the world has
    // a car (shorter than the map says) or pass where only the map has one (longer)
    let mut rng = Rng::new(3);
    let (mut shorter, mut longer) = (0usize, 0usize);
    for k in 0..20 {
        let pose = Pose2::new(3.0 + 2.5 * k as f64, 8.0, -std::f64::consts::FRAC_PI_2);
        let scan = crate::testkit::world_scan(&w, pose, 0.0, &mut rng);
        for p in &scan {
            let a = p[1].atan2(p[0]);
            let r = p[0].hypot(p[1]);
            let m = crate::raycast::raycast(&map, pose, &[a], w.max_range).unwrap()[0];
            if r < m - 0.3 {
                shorter += 1;
            } else if r > m + 0.3 {
                longer += 1;
            }
        }
    }
    assert!(
        shorter > 50 && longer > 50,
        "{shorter} shorter, {longer} longer"
    );
    // poses are drawn clear of the unmapped cars too
    let mut segs = map.clone();
    segs.extend_from_slice(&w.unmapped);
    for _ in 0..200 {
        let p = crate::testkit::world_pose(&w, &mut rng);
        assert!(crate::testkit::distance_to_segments(&segs, [p.x, p.y]) >= 0.35);
    }
}

/// A 12 × 8 m room, and a car (1.8 × 4.6 m) in it that the map has.
fn room_with_car() -> (Vec<[f64; 4]>, Vec<[f64; 4]>) {
    let room = vec![
        [0.0, 0.0, 12.0, 0.0],
        [12.0, 0.0, 12.0, 8.0],
        [12.0, 8.0, 0.0, 8.0],
        [0.0, 8.0, 0.0, 0.0],
    ];
    let car = vec![
        [7.0, 1.5, 8.8, 1.5],
        [8.8, 1.5, 8.8, 6.1],
        [8.8, 6.1, 7.0, 6.1],
        [7.0, 6.1, 7.0, 1.5],
    ];
    (room, car)
}

fn scan_of(world: &[[f64; 4]], pose: Pose2) -> Vec<[f64; 2]> {
    let angles: Vec<f64> = (0..361)
        .map(|i| -std::f64::consts::FRAC_PI_2 + std::f64::consts::PI * i as f64 / 360.0)
        .collect();
    let r = crate::raycast::raycast(world, pose, &angles, 30.0).unwrap();
    angles
        .iter()
        .zip(r)
        .filter(|(_, r)| r.is_finite())
        .map(|(a, r)| [r * a.cos(), r * a.sin()])
        .collect()
}

fn index_of(segs: &[[f64; 4]]) -> MapIndex {
    let (p, n) = sample_segments(segs, 0.025);
    MapIndex::new(p, Some(n))
        .unwrap()
        .with_cache(Some(crate::index::DEFAULT_CACHE_RESOLUTION))
        .unwrap()
}

/// Wall segments (x0, y0, x1, y1).
type Walls = Vec<[f64; 4]>;

/// The room with its car mapped, the car since gone: (the room's walls, the car's
/// outline, the index of both, the truth at (3, 4) facing the car, the scan of the room alone
/// from there).
fn car_left() -> (Walls, Walls, MapIndex, Pose2, Vec<[f64; 2]>) {
    let (room, car) = room_with_car();
    let mut map = room.clone();
    map.extend_from_slice(&car);
    let idx = index_of(&map);
    let truth = Pose2::new(3.0, 4.0, 0.0);
    let scan = scan_of(&room, truth);
    (room, car, idx, truth, scan)
}

#[test]
fn beams_through_a_mapped_car_that_left_are_not_beams_through_walls() {
    let cfg = IcpConfig::default();
    // the car has left: from the truth, facing it, a third of the beams pass through it
    let (room, car, idx, truth, scan) = car_left();
    let f = window::assess(&scan, &idx, truth, &cfg);
    assert!(f.see_through > 0.2, "{f:?}");
    assert_eq!(f.vanished, f.see_through, "{f:?}");
    // a tight fit: accepted as it is (before, its see-through failed every rule)
    let r = align(&scan, &idx, truth, &cfg).unwrap();
    assert!(
        (r.pose.x - truth.x).hypot(r.pose.y - truth.y) < 0.01,
        "{r:?}"
    );
    assert_eq!(r.start, StartPath::Plain, "{r:?}");
    // the car is there: the same beams end on it, and nothing is through anything
    let mut world = room.clone();
    world.extend_from_slice(&car);
    let seen = window::assess(&scan_of(&world, truth), &idx, truth, &cfg);
    assert_eq!((seen.see_through, seen.vanished), (0.0, 0.0), "{seen:?}");
}

#[test]
fn vanished_object_size_zero_counts_every_crossing_and_small_objects_are_up_to_it() {
    let (_, car, idx, truth, scan) = car_left();
    // off: the beams through the car that left are beams through walls again, and the
    // tight fit no longer passes as it is
    let off = IcpConfig {
        vanished_object_size: 0.0,
        ..IcpConfig::default()
    };
    let f = window::assess(&scan, &idx, truth, &off);
    assert!(f.see_through > 0.2 && f.vanished == 0.0, "{f:?}");
    let r = align(&scan, &idx, truth, &off).unwrap();
    assert_ne!(r.start, StartPath::Plain, "{r:?}");
    // a limit below the car's size: it is no small object
    let diag = {
        let (lo, hi) = car
            .iter()
            .fold(([f64::MAX; 2], [f64::MIN; 2]), |(lo, hi), p| {
                (
                    [lo[0].min(p[0]), lo[1].min(p[1])],
                    [hi[0].max(p[0]), hi[1].max(p[1])],
                )
            });
        (hi[0] - lo[0]).hypot(hi[1] - lo[1])
    };
    let below = IcpConfig {
        vanished_object_size: 0.9 * diag,
        ..IcpConfig::default()
    };
    assert_eq!(window::assess(&scan, &idx, truth, &below).vanished, 0.0);
    let above = IcpConfig {
        vanished_object_size: 1.1 * diag,
        ..IcpConfig::default()
    };
    assert_eq!(
        window::assess(&scan, &idx, truth, &above).vanished,
        f.see_through
    );
    // and a negative size is a config error naming the field
    let bad = IcpConfig {
        vanished_object_size: -1.0,
        ..IcpConfig::default()
    };
    assert!(format!("{:?}", bad.validate().unwrap_err()).contains("vanished_object_size"));
}

#[test]
fn beams_through_a_wall_still_count_past_a_car_that_left() {
    let cfg = IcpConfig::default();
    // the scan from (3, 4) facing east, read at a pose 0.7 m farther east: the east wall's
    // returns lie behind the wall, past the car that left
    let (room, car, idx, _, scan) = car_left();
    let wrong = Pose2::new(3.7, 4.0, 0.0);
    let f = window::assess(&scan, &idx, wrong, &cfg);
    assert!(f.see_through - f.vanished > 0.2, "{f:?}");
    // ... and so do beams through the wall when the car is there and seen
    let mut world = room.clone();
    world.extend_from_slice(&car);
    let f = window::assess(
        &scan_of(&world, Pose2::new(3.0, 2.0, 0.3)),
        &idx,
        Pose2::new(3.0, 2.0, 0.3 + 0.2),
        &cfg,
    );
    assert!(f.see_through - f.vanished > 0.0, "{f:?}");
}

#[test]
fn the_garages_right_fits_take_the_fast_path_past_cars_that_left() {
    // the garage (never tuned on): a fifth of its mapped cars have left, and from the small
    // start most right fits have beams through them. They are accepted without the window
    // search (before: 55 of these 100 went through the window, landing on the same pose; with the
    // see-through of cars that left alone, 18)
    let w = crate::testkit::garage_world();
    let idx = index_of(&w.map_segments());
    let cfg = IcpConfig::default();
    let cs = crate::testkit::world_cases(&w, 100, (0.3, 0.3, 10f64.to_radians()), 7);
    let (mut ok, mut windows) = (0, 0);
    for c in &cs {
        let r = align(&c.scan, &idx, c.initial, &cfg).unwrap();
        let dt = (r.pose.x - c.truth.x).hypot(r.pose.y - c.truth.y);
        ok += (dt < 0.02 && wrap_angle(r.pose.theta - c.truth.theta).abs() < 0.5f64.to_radians())
            as usize;
        windows += matches!(r.start, StartPath::Window | StartPath::WindowKeptPlain) as usize;
    }
    assert_eq!(ok, 100);
    assert!(windows <= 15, "{windows} of 100 through the window");
}

#[test]
fn a_tight_pose_with_beams_through_a_car_that_left_counts_as_searched_tight() {
    // the rule that, after a window search, accepts a tight pose as found instead of
    // sending the search on to the wide pass (`searched_tight`): a pose whose beams pass
    // only through a mapped car that left meets it (before, its 44 % see-through did not:
    // 32 more seeds, on the garage's large starts up to 13 ms). This checks the rule on
    // the right pose; the window path itself is not driven here.
    let cfg = IcpConfig::default();
    let (_, _, idx, truth, scan) = car_left();
    let r = align(&scan, &idx, truth, &cfg).unwrap();
    let f = r.fit.expect("assessed");
    assert!(f.see_through > SEARCHED_SEE_THROUGH, "{f:?}");
    assert!(searched_tight(&r, &f, truth, &cfg), "{f:?}");
}

/// The first default call builds the map's pieces (which the see-through check needs
/// once a beam meets a wall), even one whose beams meet none: a warm-up call makes the
/// later calls steady, none of them pays for the build.
#[test]
fn the_first_default_call_builds_the_maps_pieces() {
    let (p, n) = sample_segments(&office_segments(), 0.05);
    let idx = MapIndex::new(p.clone(), Some(n))
        .unwrap()
        .with_cache(Some(crate::index::DEFAULT_CACHE_RESOLUTION))
        .unwrap();
    let truth = Pose2::new(5.0, 5.0, 0.3);
    let mut rng = Rng::new(3);
    let scan = make_scan(&office_segments(), truth, 361, 30.0, 0.0, 0.0, &mut rng);
    assert!(!idx.objects_built());
    let r = align(&scan, &idx, truth, &IcpConfig::default()).unwrap();
    assert_eq!(
        r.fit.map(|f| f.see_through),
        Some(0.0),
        "no beam meets a wall"
    );
    assert!(idx.objects_built());
    // off with the vanished-object rule
    let other = MapIndex::new(p, None).unwrap();
    let cfg = IcpConfig {
        vanished_object_size: 0.0,
        ..IcpConfig::default()
    };
    align(&scan, &other, truth, &cfg).unwrap();
    assert!(!other.objects_built());
}

#[test]
fn clinic_case_76_keeps_the_truth_in_its_corridor() {
    // the bench's clinic, small start (0.3 m, 0.3 m, 10°), seed 7, case 76: the truth
    // scores highest along its corridor (a small feature; a plateau 0.65 m either side),
    // but the fit settles 0.39 m along it; on the points that tell places apart the
    // feature is a peak, while a place beyond the range's end scores higher still
    assert_clinic_case_succeeds((0.3, 0.3, 10f64.to_radians()), 76);
}

#[test]
fn the_fit_skipping_far_points_is_the_resolved_fit_bit_for_bit() {
    // review: `assessed` leaves the points with no map point within the grid's reach
    // unresolved when `far_is_nothing` holds; resolving them first (a k-d tree search each)
    // must give exactly the same fit
    let cfg = IcpConfig::default();
    let (mut compared, mut far) = (0usize, 0usize);
    for (w, idx) in family_indexes() {
        let near = 2.0 * idx.spacing() + 3.0 * cfg.expected_noise;
        assert!(window::far_is_nothing(&cfg, near));
        for c in &crate::testkit::world_cases(&w, 15, (0.3, 0.3, 10f64.to_radians()), 5) {
            // the families' rooms are closed: a few returns from far beyond the map (an open
            // door onto an unmapped hall), 40-60 m out, are the points the grid cannot answer
            let mut scan = c.scan.clone();
            scan.extend((0..12).map(|k| {
                let (a, r) = (0.5 * k as f64, 40.0 + 1.7 * k as f64);
                [r * a.cos(), r * a.sin()]
            }));
            let mut ws = Workspace::default();
            let r = align_plain(&scan, &idx, c.initial, &cfg, &mut ws);
            if ws.nn_pose.is_none() {
                continue;
            }
            let skipped = window::assess_with(&scan, &idx, r.pose, &cfg, &ws.nn);
            far += ws.nn.iter().filter(|&&j| j == UNKNOWN).count();
            ws.resolve_nn(&idx);
            assert!(!ws.nn.contains(&UNKNOWN));
            let resolved = window::assess_with(&scan, &idx, r.pose, &cfg, &ws.nn);
            assert_eq!(
                format!("{skipped:?}"),
                format!("{resolved:?}"),
                "{}",
                w.name
            );
            compared += 1;
        }
    }
    assert!(compared >= 50, "{compared}");
    assert!(far > 0, "no case had a point beyond the grid's reach");
}

#[test]
fn align_does_not_depend_on_the_calls_before_it() {
    // review: `align` keeps its buffers between calls on a thread; a call's result must be
    // that of a fresh workspace whatever ran before it (two maps, both orders)
    let cfg = IcpConfig::default();
    let mut sets = Vec::new();
    for (w, idx) in family_indexes().into_iter().take(3) {
        let cs = crate::testkit::world_cases(&w, 8, (1.0, 0.5, 25f64.to_radians()), 11);
        sets.push((idx, cs));
    }
    let fresh: Vec<Vec<String>> = sets
        .iter()
        .map(|(idx, cs)| {
            cs.iter()
                .map(|c| {
                    check_inputs(&c.scan, c.initial, &cfg).unwrap();
                    let mut ws = Workspace::default();
                    format!(
                        "{:?}",
                        align_unchecked(&c.scan, idx, c.initial, &cfg, &mut ws)
                    )
                })
                .collect()
        })
        .collect();
    for order in [[0usize, 1, 2], [2, 1, 0], [1, 0, 2]] {
        for &k in &order {
            let (idx, cs) = &sets[k];
            for (c, want) in cs.iter().zip(&fresh[k]) {
                let got = align(&c.scan, idx, c.initial, &cfg).unwrap();
                assert_eq!(&format!("{got:?}"), want, "set {k} in order {order:?}");
            }
        }
    }
}

/// Every family world (the team's and the unseen ones) with its map index
/// ([`world_index`]).
fn family_indexes() -> Vec<(crate::testkit::World, MapIndex)> {
    crate::testkit::all_worlds()
        .into_iter()
        .chain(crate::testkit::unseen_worlds())
        .map(world_index)
        .collect()
}
