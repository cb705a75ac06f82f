//! A deterministic office world and scan generator for tests and benchmarks (no external
//! randomness: a SplitMix64 generator with Box–Muller normals).

use crate::raycast::{raycast, Segment};
use crate::se2::Pose2;

/// SplitMix64: small, fast, deterministic.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed ^ 0x9E37_79B9_7F4A_7C15)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
    pub fn sign(&mut self) -> f64 {
        if self.next_u64() & 1 == 0 {
            1.0
        } else {
            -1.0
        }
    }
}

/// An office floor of 30 m × 20 m: outer walls, a corridor, rooms with door gaps, a
/// diagonal wall and pillars.
pub fn office_segments() -> Vec<Segment> {
    let mut s: Vec<Segment> = vec![
        [0.0, 0.0, 30.0, 0.0],
        [30.0, 0.0, 30.0, 20.0],
        [30.0, 20.0, 0.0, 20.0],
        [0.0, 20.0, 0.0, 0.0],
    ];
    // corridor walls at y = 8 and y = 11, with door gaps of 1 m
    for &y in &[8.0, 11.0] {
        let mut x = 0.0;
        while x < 30.0 {
            let end = (x + 5.0f64).min(30.0);
            s.push([x, y, end - 1.0, y]);
            x = end;
        }
    }
    // room dividers
    for &x in &[6.0, 12.0, 18.0, 24.0] {
        s.push([x, 0.0, x, 8.0]);
        s.push([x, 11.0, x, 20.0]);
    }
    // a diagonal wall and some furniture-like boxes (mapped)
    s.push([1.0, 14.0, 4.5, 18.5]);
    for &(cx, cy, w) in &[
        (9.0, 4.0, 0.6),
        (15.0, 15.5, 0.8),
        (27.0, 5.0, 0.5),
        (20.5, 16.0, 1.2),
    ] {
        let h = w / 2.0;
        s.push([cx - h, cy - h, cx + h, cy - h]);
        s.push([cx + h, cy - h, cx + h, cy + h]);
        s.push([cx + h, cy + h, cx - h, cy + h]);
        s.push([cx - h, cy + h, cx - h, cy - h]);
    }
    s
}

/// The four walls of an empty `w` x `h` rectangle with a corner at the origin.
pub fn rectangle(w: f64, h: f64) -> Vec<Segment> {
    vec![
        [0.0, 0.0, w, 0.0],
        [w, 0.0, w, h],
        [w, h, 0.0, h],
        [0.0, h, 0.0, 0.0],
    ]
}

/// Sample segments every `spacing` metres; each sample carries its segment's unit normal.
pub fn sample_segments(segments: &[Segment], spacing: f64) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let mut pts = Vec::new();
    let mut nrm = Vec::new();
    for s in segments {
        let d = [s[2] - s[0], s[3] - s[1]];
        let len = (d[0] * d[0] + d[1] * d[1]).sqrt();
        if len == 0.0 {
            continue;
        }
        let n = [-d[1] / len, d[0] / len];
        let k = (len / spacing).floor() as usize;
        for i in 0..=k {
            let t = (i as f64 * spacing).min(len) / len;
            pts.push([s[0] + t * d[0], s[1] + t * d[1]]);
            nrm.push(n);
        }
    }
    (pts, nrm)
}

/// A benchmark case: a noisy scan with unmapped obstacles, its true pose and a perturbed
/// initial pose.
#[derive(Clone, Debug)]
pub struct Case {
    pub scan: Vec<[f64; 2]>,
    pub truth: Pose2,
    pub initial: Pose2,
}

/// Free poses in the office (room centres and corridor), jittered.
pub fn random_pose(rng: &mut Rng) -> Pose2 {
    let centres = [
        (3.0, 4.0),
        (9.0, 6.0),
        (15.0, 4.0),
        (21.0, 4.0),
        (27.0, 3.0),
        (3.0, 9.5),
        (10.0, 9.5),
        (16.0, 9.5),
        (22.0, 9.5),
        (28.0, 9.5),
        (8.0, 15.0),
        (15.0, 13.0),
        (21.0, 13.0),
        (27.0, 16.0),
    ];
    let (cx, cy) = centres[(rng.next_u64() % centres.len() as u64) as usize];
    let jx = if (9.0..10.0).contains(&cy) { 2.0 } else { 1.0 };
    let jy = if (9.0..10.0).contains(&cy) { 0.5 } else { 1.0 };
    Pose2::new(
        cx + rng.range(-jx, jx),
        cy + rng.range(-jy, jy),
        rng.range(-std::f64::consts::PI, std::f64::consts::PI),
    )
}

/// A 180° scan of `beams` beams from `pose` with Gaussian range noise `noise` and a
/// fraction `outliers` of beams hitting unmapped obstacles in front of the walls.
pub fn make_scan(
    segments: &[Segment],
    pose: Pose2,
    beams: usize,
    max_range: f64,
    noise: f64,
    outliers: f64,
    rng: &mut Rng,
) -> Vec<[f64; 2]> {
    let angles: Vec<f64> = (0..beams)
        .map(|i| {
            -std::f64::consts::FRAC_PI_2 + std::f64::consts::PI * i as f64 / (beams - 1) as f64
        })
        .collect();
    let ranges = raycast(segments, pose, &angles, max_range).expect("finite world");
    let mut out = Vec::with_capacity(beams);
    for (a, r) in angles.iter().zip(ranges) {
        if !r.is_finite() {
            continue;
        }
        let r = if rng.uniform() < outliers {
            r * rng.range(0.2, 0.85)
        } else {
            r + noise * rng.normal()
        };
        out.push([r * a.cos(), r * a.sin()]);
    }
    out
}

/// `n` deterministic cases with initial errors of the given magnitudes (random signs).
pub fn cases(
    segments: &[Segment],
    n: usize,
    err: (f64, f64, f64),
    noise: f64,
    outliers: f64,
    seed: u64,
) -> Vec<Case> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let truth = random_pose(&mut rng);
            let scan = make_scan(segments, truth, 361, 30.0, noise, outliers, &mut rng);
            let initial = Pose2::new(
                truth.x + rng.sign() * err.0,
                truth.y + rng.sign() * err.1,
                truth.theta + rng.sign() * err.2,
            );
            Case {
                scan,
                truth,
                initial,
            }
        })
        .collect()
}
