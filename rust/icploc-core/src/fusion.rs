//! The scan match as a measurement (the localizer's `icploc.fusion.scan_covariance`): the
//! covariance of an ICP pose from the information `H = sum J' J` of its fit, calibrated
//! for correlated beams and the map's resolution.
//!
//! `Sigma = (f H_sym + eps I)^-1` with `f = min(independent_beams, n) / (n s^2)`, `n` the
//! fit's inliers, `s^2` its mean squared residual floored at the map's expected one, and
//! `eps = 1e-6` (a direction the scan does not constrain gets a variance of about 1e6).
//! The arithmetic follows the Python it replaces operation for operation (same order, same
//! cofactor inverse), so the covariance is the same to the bit.
//!
//! When the fit may hold its position along some direction with fewer than
//! `min_axis_beams` beams (the smallest eigenvalue of H's translational block), Python
//! drops that direction with an eigen-decomposition: [`scan_covariance`] returns None
//! there and leaves it to that code, so that the result stays numpy's.

/// The variance given to a direction the scan does not constrain (m² / rad²).
pub const HUGE: f64 = 1e6;

/// The inverse of a symmetric 3x3 by cofactors (only the upper triangle is read); None
/// when its determinant is not positive and finite.
pub fn inv3_sym(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let (s00, s01, s02) = (m[0][0], m[0][1], m[0][2]);
    let (s11, s12, s22) = (m[1][1], m[1][2], m[2][2]);
    let c00 = s11 * s22 - s12 * s12;
    let c01 = s02 * s12 - s01 * s22;
    let c02 = s01 * s12 - s02 * s11;
    let det = s00 * c00 + s01 * c01 + s02 * c02;
    if !(det > 0.0 && det.is_finite()) {
        return None;
    }
    let c11 = s00 * s22 - s02 * s02;
    let c12 = s01 * s02 - s00 * s12;
    let c22 = s00 * s11 - s01 * s01;
    let k = 1.0 / det;
    Some([
        [c00 * k, c01 * k, c02 * k],
        [c01 * k, c11 * k, c12 * k],
        [c02 * k, c12 * k, c22 * k],
    ])
}

/// False only when the smallest eigenvalue of `h`'s symmetric translational block is
/// surely at least `bound` (closed form; the margin, 1e-8 of the entries, is ten times the
/// Python gate's, so that wherever this says "surely" Python's gate says so too).
pub fn may_be_below(h: &[[f64; 3]; 3], bound: f64) -> bool {
    let a = h[0][0];
    let b = 0.5 * (h[0][1] + h[1][0]);
    let c = h[1][1];
    let low = 0.5 * (a + c) - (0.5 * (a - c)).hypot(b);
    !(low - bound > 1e-8 * (a.abs() + b.abs() + c.abs() + bound.abs() + 1.0))
}

/// The covariance of an ICP pose (see the module docstring); None when a direction may be
/// held by fewer than `min_axis_beams` beams (the caller's eigen-decomposition decides).
pub fn scan_covariance(
    information: &[[f64; 3]; 3],
    inliers: i64,
    mse: f64,
    sigma_floor: f64,
    independent_beams: f64,
    min_axis_beams: f64,
) -> Option<[[f64; 3]; 3]> {
    let h = information;
    let finite = h.iter().flatten().all(|v| v.is_finite());
    if min_axis_beams > 0.0 && finite && may_be_below(h, min_axis_beams) {
        return None;
    }
    let n = inliers.max(1) as f64;
    let m = if mse.is_finite() { mse } else { 0.0 };
    let floor = sigma_floor * sigma_floor;
    let s2 = if floor > m { floor } else { m };
    let f = (if n < independent_beams {
        n
    } else {
        independent_beams
    }) / (n * s2);
    let eps = 1.0 / HUGE;
    let info = [
        [
            h[0][0] * f + eps,
            0.5 * (h[0][1] + h[1][0]) * f,
            0.5 * (h[0][2] + h[2][0]) * f,
        ],
        [0.0, h[1][1] * f + eps, 0.5 * (h[1][2] + h[2][1]) * f],
        [0.0, 0.0, h[2][2] * f + eps],
    ];
    Some(inv3_sym(&info).unwrap_or([[HUGE, 0.0, 0.0], [0.0, HUGE, 0.0], [0.0, 0.0, HUGE]]))
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // the 3x3 checks index rows and columns
mod tests {
    use super::*;

    fn room_information(beams_x: f64, beams_y: f64) -> [[f64; 3]; 3] {
        // unit normals: beams_x along x, beams_y along y, the heading held by both
        [
            [beams_x, 0.0, 0.1],
            [0.0, beams_y, -0.2],
            [0.1, -0.2, 4.0 * (beams_x + beams_y)],
        ]
    }

    #[test]
    fn covariance_inverts_the_scaled_information() {
        let h = room_information(100.0, 80.0);
        let c = scan_covariance(&h, 180, 0.0004, 0.01, 20.0, 8.0).unwrap();
        // f = 20 / (180 * 4e-4): Sigma (f H + eps I) = I
        let f = 20.0 / (180.0 * 0.0004);
        for i in 0..3 {
            for j in 0..3 {
                let mut s = 0.0;
                for k in 0..3 {
                    let a = h[k][j] * f + if k == j { 1e-6 } else { 0.0 };
                    s += c[i][k] * a;
                }
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((s - want).abs() < 1e-9, "({i}, {j}): {s}");
            }
        }
        assert_eq!(c[0][1], c[1][0]);
    }

    #[test]
    fn the_residual_floor_and_the_beam_count_scale_it() {
        let h = room_information(100.0, 80.0);
        // a tiny mse is floored at sigma_floor^2
        let floored = scan_covariance(&h, 180, 1e-9, 0.02, 20.0, 0.0).unwrap();
        let at_floor = scan_covariance(&h, 180, 0.0004, 0.02, 20.0, 0.0).unwrap();
        assert_eq!(floored, at_floor);
        // fewer independent beams: less information, a wider covariance
        let fewer = scan_covariance(&h, 180, 0.0004, 0.02, 10.0, 0.0).unwrap();
        assert!((fewer[0][0] / at_floor[0][0] - 2.0).abs() < 1e-6);
        // a non-finite mse counts as zero (the floor)
        assert_eq!(
            scan_covariance(&h, 180, f64::NAN, 0.02, 20.0, 0.0).unwrap(),
            at_floor
        );
    }

    #[test]
    fn a_weak_axis_is_left_to_the_eigen_decomposition() {
        // a corridor: 3 beams along x, the minimum 8
        let corridor = room_information(3.0, 150.0);
        assert!(may_be_below(&corridor, 8.0));
        assert_eq!(scan_covariance(&corridor, 153, 4e-4, 0.01, 20.0, 8.0), None);
        // without the rule (0) it is computed
        assert!(scan_covariance(&corridor, 153, 4e-4, 0.01, 20.0, 0.0).is_some());
        assert!(!may_be_below(&room_information(100.0, 80.0), 8.0));
    }

    #[test]
    fn no_information_is_a_huge_covariance() {
        let nan = [[f64::NAN; 3]; 3];
        let c = scan_covariance(&nan, 0, 0.0, 0.01, 20.0, 8.0).unwrap();
        assert_eq!(c, [[HUGE, 0.0, 0.0], [0.0, HUGE, 0.0], [0.0, 0.0, HUGE]]);
        assert!(inv3_sym(&[[1.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]]).is_none());
    }
}
