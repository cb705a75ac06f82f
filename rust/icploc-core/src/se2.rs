//! Planar rigid transforms (SE(2)).

/// Wrap an angle to (-pi, pi].
#[inline]
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let mut w = a % two_pi;
    if w <= -std::f64::consts::PI {
        w += two_pi;
    } else if w > std::f64::consts::PI {
        w -= two_pi;
    }
    w
}

/// A pose (x, y, theta): the frame's origin and heading in the parent frame.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Pose2 {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl Pose2 {
    #[inline]
    pub const fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }

    #[inline]
    pub const fn identity() -> Self {
        Self::new(0.0, 0.0, 0.0)
    }

    #[inline]
    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.theta.is_finite()
    }

    /// `self ⊕ other`: `other` expressed in `self`'s frame, mapped to the parent frame.
    #[inline]
    pub fn compose(&self, other: &Pose2) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2::new(
            self.x + c * other.x - s * other.y,
            self.y + s * other.x + c * other.y,
            wrap_angle(self.theta + other.theta),
        )
    }

    /// The inverse transform.
    #[inline]
    pub fn inverse(&self) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2::new(
            -c * self.x - s * self.y,
            s * self.x - c * self.y,
            wrap_angle(-self.theta),
        )
    }

    /// Map a point from this frame into the parent frame.
    #[inline]
    pub fn transform(&self, p: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.theta.sin_cos();
        [self.x + c * p[0] - s * p[1], self.y + s * p[0] + c * p[1]]
    }

    /// Same pose with theta wrapped to (-pi, pi].
    #[inline]
    pub fn normalized(&self) -> Pose2 {
        Pose2::new(self.x, self.y, wrap_angle(self.theta))
    }
}

impl From<[f64; 3]> for Pose2 {
    fn from(a: [f64; 3]) -> Self {
        Pose2::new(a[0], a[1], a[2])
    }
}

impl From<Pose2> for [f64; 3] {
    fn from(p: Pose2) -> Self {
        [p.x, p.y, p.theta]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compose_inverse_is_identity() {
        let a = Pose2::new(1.0, -2.0, 0.7);
        let b = a.compose(&a.inverse());
        assert!(b.x.abs() < 1e-12 && b.y.abs() < 1e-12 && b.theta.abs() < 1e-12);
    }

    #[test]
    fn wrap() {
        assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_angle(-std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_angle(0.5) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn transform_point() {
        let a = Pose2::new(1.0, 2.0, std::f64::consts::FRAC_PI_2);
        let p = a.transform([1.0, 0.0]);
        assert!((p[0] - 1.0).abs() < 1e-12 && (p[1] - 3.0).abs() < 1e-12);
    }
}
