//! The odometry noise factor of one scan (the localizer's online noise estimate,
//! `icploc.motion.NoiseGain`): the factor `g` on the prediction's covariance `P` that makes
//! the normalised innovation `v' (g P + R)^-1 v` of a trusted scan pose equal to the median
//! of its chi-square distribution (3 degrees of freedom).
//!
//! The statistic falls as `g` grows; `g` is found by bisection on its logarithm within
//! `[1e-3, 4 max_gain]` (40 halvings), counted at an end when the root lies beyond it.
//! Each step solves a 3x3 system: in numpy that was ~40 `np.linalg.solve` calls a scan.

/// The median of the chi-square distribution with 3 degrees of freedom.
pub const CHI2_3_MEDIAN: f64 = 2.366;

/// The lower end of the factor's bracket.
pub const MIN_FACTOR: f64 = 1e-3;

/// Bisection steps on `log g`.
pub const STEPS: usize = 40;

/// `v' S^-1 v` for `S = g P + R`, by Gaussian elimination with partial pivoting (as
/// LAPACK's `gesv`); infinite when `S` is singular.
#[allow(clippy::needless_range_loop)]
pub fn nis(v: &[f64; 3], p: &[[f64; 3]; 3], g: f64, r: &[[f64; 3]; 3]) -> f64 {
    let mut a = [[0.0f64; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            a[i][j] = g * p[i][j] + r[i][j];
        }
    }
    match solve3(a, *v) {
        Some(x) => v[0] * x[0] + v[1] * x[1] + v[2] * x[2],
        None => f64::INFINITY,
    }
}

/// `A x = b` by LU with partial pivoting (the pivot the first largest in magnitude, the
/// multipliers scaled by the pivot's reciprocal as LAPACK's `getf2` does); None when a
/// pivot is exactly zero (numpy's `LinAlgError`).
#[allow(clippy::needless_range_loop)] // LU on a 3x3: rows and columns by index
pub fn solve3(mut a: [[f64; 3]; 3], mut b: [f64; 3]) -> Option<[f64; 3]> {
    for k in 0..3 {
        let mut piv = k;
        for i in k + 1..3 {
            if a[i][k].abs() > a[piv][k].abs() {
                piv = i;
            }
        }
        if a[piv][k] == 0.0 {
            return None;
        }
        if piv != k {
            a.swap(piv, k);
            b.swap(piv, k);
        }
        let inv = 1.0 / a[k][k];
        for i in k + 1..3 {
            let l = a[i][k] * inv;
            a[i][k] = l;
            for j in k + 1..3 {
                a[i][j] -= l * a[k][j];
            }
            b[i] -= l * b[k];
        }
    }
    let mut x = [0.0f64; 3];
    for i in (0..3).rev() {
        let mut s = b[i];
        for j in i + 1..3 {
            s -= a[i][j] * x[j];
        }
        x[i] = s / a[i][i];
    }
    Some(x)
}

/// The factor `g` of one trusted scan pose (see the module docstring): `v` the scan pose
/// minus the prediction (heading wrapped), `p` the prediction's covariance, `r` the scan
/// pose's. None when any input is not finite (no evidence).
pub fn noise_factor(
    v: &[f64; 3],
    p: &[[f64; 3]; 3],
    r: &[[f64; 3]; 3],
    max_gain: f64,
) -> Option<f64> {
    let finite = v.iter().all(|x| x.is_finite())
        && p.iter().flatten().all(|x| x.is_finite())
        && r.iter().flatten().all(|x| x.is_finite());
    if !finite {
        return None;
    }
    let (mut lo, mut hi) = (MIN_FACTOR, max_gain * 4.0);
    if nis(v, p, hi, r) > CHI2_3_MEDIAN {
        return Some(hi); // beyond what any gain explains: counted at the top
    }
    if nis(v, p, lo, r) < CHI2_3_MEDIAN {
        return Some(lo); // the scan's own noise explains it
    }
    for _ in 0..STEPS {
        let mid = (lo * hi).sqrt();
        if nis(v, p, mid, r) > CHI2_3_MEDIAN {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some((lo * hi).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn diag(a: f64, b: f64, c: f64) -> [[f64; 3]; 3] {
        [[a, 0.0, 0.0], [0.0, b, 0.0], [0.0, 0.0, c]]
    }

    #[test]
    fn solve3_inverts_a_pivoting_system() {
        // a zero leading entry needs the row swap
        let a = [[0.0, 2.0, 1.0], [1.0, 1.0, 0.0], [3.0, 0.0, 1.0]];
        let x_true = [0.5, -1.25, 2.0];
        let b = [
            a[0][0] * x_true[0] + a[0][1] * x_true[1] + a[0][2] * x_true[2],
            a[1][0] * x_true[0] + a[1][1] * x_true[1] + a[1][2] * x_true[2],
            a[2][0] * x_true[0] + a[2][1] * x_true[1] + a[2][2] * x_true[2],
        ];
        let x = solve3(a, b).unwrap();
        for i in 0..3 {
            assert!((x[i] - x_true[i]).abs() < 1e-14, "{x:?}");
        }
        assert!(solve3([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]], b).is_none());
    }

    #[test]
    fn the_factor_solves_the_median_equation() {
        // diagonal: v' (g P + R)^-1 v = sum v_i^2 / (g p_i + r_i); with R = 0 and
        // v_i^2 = p_i each term is 1/g, so g = 3 / 2.366
        let p = diag(0.01, 0.04, 0.001);
        let v = [0.1, 0.2, 0.001f64.sqrt()];
        let g = noise_factor(&v, &p, &diag(0.0, 0.0, 0.0), 10.0).unwrap();
        assert!((g - 3.0 / CHI2_3_MEDIAN).abs() < 1e-9 * g, "g {g}");
        let at = nis(&v, &p, g, &diag(0.0, 0.0, 0.0));
        assert!((at - CHI2_3_MEDIAN).abs() < 1e-9, "nis {at}");
        // with a measurement covariance the factor is smaller (R explains part of v)
        let r = diag(0.005, 0.01, 0.0002);
        let gr = noise_factor(&v, &p, &r, 10.0).unwrap();
        assert!(gr < g);
        assert!((nis(&v, &p, gr, &r) - CHI2_3_MEDIAN).abs() < 1e-9);
    }

    #[test]
    fn the_factor_is_clamped_to_its_bracket_and_needs_finite_input() {
        let p = diag(0.01, 0.01, 0.001);
        let r = diag(0.01, 0.01, 0.001);
        // far off: no gain explains it
        assert_eq!(noise_factor(&[5.0, 0.0, 0.0], &p, &r, 10.0), Some(40.0));
        // right on: the scan's own noise explains it
        assert_eq!(
            noise_factor(&[0.0, 0.0, 0.0], &p, &r, 10.0),
            Some(MIN_FACTOR)
        );
        assert_eq!(noise_factor(&[f64::NAN, 0.0, 0.0], &p, &r, 10.0), None);
        let mut bad = p;
        bad[1][2] = f64::INFINITY;
        assert_eq!(noise_factor(&[0.1, 0.0, 0.0], &bad, &r, 10.0), None);
    }
}
