//! Ray casting against wall segments: simulated scans and exact visibility.

use crate::error::{IcpError, Result};
use crate::se2::Pose2;

/// A wall segment [x1, y1, x2, y2].
pub type Segment = [f64; 4];

/// Check that segments are finite.
pub fn check_segments(segments: &[Segment]) -> Result<()> {
    match segments
        .iter()
        .position(|s| s.iter().any(|v| !v.is_finite()))
    {
        Some(row) => Err(IcpError::NonFinite {
            what: "segments".into(),
            row,
        }),
        None => Ok(()),
    }
}

/// Distance along the ray (origin o, unit direction d) to segment s, if hit at t > 0.
#[inline]
fn hit(o: [f64; 2], d: [f64; 2], s: &Segment) -> Option<f64> {
    let e = [s[2] - s[0], s[3] - s[1]];
    let den = d[0] * e[1] - d[1] * e[0];
    if den.abs() < 1e-15 {
        return None;
    }
    let w = [s[0] - o[0], s[1] - o[1]];
    let t = (w[0] * e[1] - w[1] * e[0]) / den;
    let u = (w[0] * d[1] - w[1] * d[0]) / den;
    if t > 1e-9 && (-1e-12..=1.0 + 1e-12).contains(&u) {
        Some(t)
    } else {
        None
    }
}

/// Range along each beam from `pose` (angles in the sensor frame) to the nearest segment,
/// `f64::INFINITY` when nothing is hit within `max_range`.
pub fn raycast(
    segments: &[Segment],
    pose: Pose2,
    angles: &[f64],
    max_range: f64,
) -> Result<Vec<f64>> {
    check_segments(segments)?;
    if !pose.is_finite() {
        return Err(IcpError::InvalidInput {
            what: "pose".into(),
            reason: "must be finite".into(),
        });
    }
    if !(max_range > 0.0) || max_range.is_nan() {
        return Err(IcpError::InvalidConfig {
            field: "max_range",
            value: max_range.to_string(),
            reason: "must be positive",
        });
    }
    if let Some(row) = angles.iter().position(|a| !a.is_finite()) {
        return Err(IcpError::NonFinite {
            what: "angles".into(),
            row,
        });
    }
    let o = [pose.x, pose.y];
    // keep only segments that come within max_range of the origin
    let near: Vec<Segment> = segments
        .iter()
        .copied()
        .filter(|s| point_segment_distance(o, s) <= max_range)
        .collect();
    Ok(angles
        .iter()
        .map(|a| {
            let (sn, cs) = (pose.theta + a).sin_cos();
            let d = [cs, sn];
            let best = near
                .iter()
                .filter_map(|s| hit(o, d, s))
                .fold(f64::INFINITY, f64::min);
            if best <= max_range {
                best
            } else {
                f64::INFINITY
            }
        })
        .collect())
}

/// Euclidean distance from point p to segment s.
pub fn point_segment_distance(p: [f64; 2], s: &Segment) -> f64 {
    let e = [s[2] - s[0], s[3] - s[1]];
    let l2 = e[0] * e[0] + e[1] * e[1];
    let t = if l2 > 0.0 {
        (((p[0] - s[0]) * e[0] + (p[1] - s[1]) * e[1]) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let q = [s[0] + t * e[0], s[1] + t * e[1]];
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_room_ranges() {
        let segs = [
            [0.0, 0.0, 4.0, 0.0],
            [4.0, 0.0, 4.0, 4.0],
            [4.0, 4.0, 0.0, 4.0],
            [0.0, 4.0, 0.0, 0.0],
        ];
        let pose = Pose2::new(1.0, 2.0, 0.0);
        let pi = std::f64::consts::PI;
        let r = raycast(&segs, pose, &[0.0, pi / 2.0, pi, -pi / 2.0, pi / 4.0], 30.0).unwrap();
        assert!((r[0] - 3.0).abs() < 1e-12);
        assert!((r[1] - 2.0).abs() < 1e-12);
        assert!((r[2] - 1.0).abs() < 1e-12);
        assert!((r[3] - 2.0).abs() < 1e-12);
        assert!((r[4] - 2.0 * 2f64.sqrt()).abs() < 1e-12);
        let r = raycast(&segs, pose, &[0.0], 2.5).unwrap();
        assert!(r[0].is_infinite());
    }

    #[test]
    fn bad_input() {
        assert!(raycast(&[[0.0, 0.0, f64::NAN, 1.0]], Pose2::identity(), &[0.0], 1.0).is_err());
        assert!(raycast(&[], Pose2::new(f64::NAN, 0.0, 0.0), &[0.0], 1.0).is_err());
        assert!(raycast(&[], Pose2::identity(), &[0.0], 0.0).is_err());
        assert!(raycast(&[], Pose2::identity(), &[f64::INFINITY], 1.0).is_err());
        assert_eq!(raycast(&[], Pose2::identity(), &[], 1.0).unwrap().len(), 0);
    }
}
