//! The closed-form registration of Besl & McKay as used by the paper (eq. 5–9): centroids,
//! cross-covariance, the 4×4 symmetric quaternion matrix, its top eigenvector, translation
//! from the centroids — kept to a rotation about z for planar data.

use nalgebra::{Matrix3, Matrix4, SymmetricEigen};

/// Running weighted sums of point pairs (p: data/scan, x: model/map).
#[derive(Clone, Copy, Debug, Default)]
pub struct CrossCovariance {
    sw: f64,
    sp: [f64; 2],
    sx: [f64; 2],
    spx: [[f64; 2]; 2],
}

/// A planar rigid transform with x ≈ R(theta) p + t.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Registration {
    pub theta: f64,
    pub t: [f64; 2],
    /// The unit quaternion (q0, q1, q2, q3) of the chosen eigenvector, q0 >= 0.
    pub quaternion: [f64; 4],
}

impl CrossCovariance {
    #[inline]
    pub fn add(&mut self, p: [f64; 2], x: [f64; 2], w: f64) {
        self.sw += w;
        self.sp[0] += w * p[0];
        self.sp[1] += w * p[1];
        self.sx[0] += w * x[0];
        self.sx[1] += w * x[1];
        self.spx[0][0] += w * p[0] * x[0];
        self.spx[0][1] += w * p[0] * x[1];
        self.spx[1][0] += w * p[1] * x[0];
        self.spx[1][1] += w * p[1] * x[1];
    }

    pub fn weight(&self) -> f64 {
        self.sw
    }

    /// Centroids u_p, u_x (eq. 5, weighted).
    pub fn centroids(&self) -> ([f64; 2], [f64; 2]) {
        let w = self.sw;
        (
            [self.sp[0] / w, self.sp[1] / w],
            [self.sx[0] / w, self.sx[1] / w],
        )
    }

    /// The cross-covariance Σ_px (eq. 6) as a 3×3 matrix with a zero z row and column.
    pub fn sigma(&self) -> Matrix3<f64> {
        let (up, ux) = self.centroids();
        let w = self.sw;
        let mut s = Matrix3::zeros();
        for a in 0..2 {
            for b in 0..2 {
                s[(a, b)] = self.spx[a][b] / w - up[a] * ux[b];
            }
        }
        s
    }

    /// Solve for the rotation and translation. `None` without positive total weight.
    pub fn solve(&self) -> Option<Registration> {
        if !(self.sw > 0.0) || !self.sw.is_finite() {
            return None;
        }
        let s = self.sigma();
        let q = quaternion_matrix(&s);
        let eig = SymmetricEigen::new(q);
        let quat = top_yaw_eigenvector(&eig)?;
        let theta = 2.0 * quat[3].atan2(quat[0]);
        let (sn, cs) = theta.sin_cos();
        let (up, ux) = self.centroids();
        // eq. 8: q_T = u_x - R u_p
        let t = [
            ux[0] - (cs * up[0] - sn * up[1]),
            ux[1] - (sn * up[0] + cs * up[1]),
        ];
        Some(Registration {
            theta,
            t,
            quaternion: quat,
        })
    }
}

/// eq. 7: Q(Σ) = [[tr Σ, Δᵀ], [Δ, Σ + Σᵀ − tr(Σ) I₃]], Δ = [A23, A31, A12], A = Σ − Σᵀ.
pub fn quaternion_matrix(s: &Matrix3<f64>) -> Matrix4<f64> {
    let a = s - s.transpose();
    let delta = [a[(1, 2)], a[(2, 0)], a[(0, 1)]];
    let tr = s.trace();
    let b = s + s.transpose() - Matrix3::identity() * tr;
    let mut q = Matrix4::zeros();
    q[(0, 0)] = tr;
    for i in 0..3 {
        q[(0, i + 1)] = delta[i];
        q[(i + 1, 0)] = delta[i];
        for j in 0..3 {
            q[(i + 1, j + 1)] = b[(i, j)];
        }
    }
    q
}

/// The eigenvector of the largest eigenvalue among those that are rotations about z.
///
/// For planar data Q splits into a (q0, q3) block — rotations about z — and a (q1, q2)
/// block — 180° turns about an in-plane axis, i.e. mirror images of the plane. The latter
/// can have the larger eigenvalue (a scan that fits its mirror image better), and is never
/// an answer for a robot on the floor: we take the best eigenvector of the yaw block.
fn top_yaw_eigenvector(eig: &SymmetricEigen<f64, nalgebra::U4>) -> Option<[f64; 4]> {
    let mut order = [0usize, 1, 2, 3];
    order.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
    for &k in &order {
        let v = eig.eigenvectors.column(k);
        let yaw = v[0] * v[0] + v[3] * v[3];
        if yaw >= 0.5 {
            let n = yaw.sqrt();
            let (mut q0, mut q3) = (v[0] / n, v[3] / n);
            if q0 < 0.0 {
                q0 = -q0;
                q3 = -q3;
            }
            return Some([q0, 0.0, 0.0, q3]);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pairs(theta: f64, t: [f64; 2]) -> Vec<([f64; 2], [f64; 2])> {
        let pts = [[1.0, 0.0], [0.0, 2.0], [-1.5, 0.3], [2.0, -1.0], [0.3, 0.7]];
        let (s, c) = theta.sin_cos();
        pts.iter()
            .map(|p| (*p, [c * p[0] - s * p[1] + t[0], s * p[0] + c * p[1] + t[1]]))
            .collect()
    }

    #[test]
    fn recovers_rotation_and_translation() {
        for &theta in &[0.0, 0.3, -1.2, 3.0, -3.1] {
            let mut cc = CrossCovariance::default();
            for (p, x) in pairs(theta, [0.5, -2.0]) {
                cc.add(p, x, 1.0);
            }
            let r = cc.solve().unwrap();
            assert!(
                (crate::se2::wrap_angle(r.theta - theta)).abs() < 1e-12,
                "{theta}"
            );
            assert!((r.t[0] - 0.5).abs() < 1e-12 && (r.t[1] + 2.0).abs() < 1e-12);
            assert!(r.quaternion[0] >= 0.0);
        }
    }

    #[test]
    fn mirror_image_is_never_the_answer() {
        // x is p mirrored about the x axis: the best 3D fit is a 180° flip about x.
        let pts = [[1.0, 0.1], [2.0, 1.0], [3.0, -0.5], [0.5, 2.0]];
        let mut cc = CrossCovariance::default();
        for p in pts {
            cc.add(p, [p[0], -p[1]], 1.0);
        }
        let q = quaternion_matrix(&cc.sigma());
        let eig = SymmetricEigen::new(q);
        let imax = eig.eigenvalues.imax();
        let v = eig.eigenvectors.column(imax);
        // the unconstrained top eigenvector is a flip ...
        assert!(v[1] * v[1] + v[2] * v[2] > 0.5);
        // ... and the solve still returns a yaw.
        let r = cc.solve().unwrap();
        assert_eq!(r.quaternion[1], 0.0);
        assert_eq!(r.quaternion[2], 0.0);
        assert!(r.theta.is_finite());
    }

    #[test]
    fn zero_weight_is_none() {
        assert!(CrossCovariance::default().solve().is_none());
    }
}
