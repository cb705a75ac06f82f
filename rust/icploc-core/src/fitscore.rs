//! The verification evidence of a scan at one pose (the localizer's `FitChecker`): the
//! share of beams that end on a mapped wall and the point-to-line RMS residual of those
//! that do.
//!
//! The localizer scores several poses a scan (the fit, the prediction, a rival, the
//! retries), each once per scan; this is that loop in one call. It reproduces the numpy
//! computation it replaces operation for operation (the same subsample of beams, the same
//! rounding order of the transform, numpy's pairwise summation for the mean), so that the
//! localizer's decisions, which compare these figures against thresholds, stay the same.

use crate::index::MapIndex;
use crate::se2::Pose2;

/// The evidence of one scan at one pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitScore {
    /// Share of the checked beams whose nearest map point is closer than the hit distance.
    pub hit: f64,
    /// RMS point-to-line residual of the beams that hit (m); infinite when none does.
    pub rms: f64,
    /// Beams checked (at most `max_beams`).
    pub beams: usize,
    /// Beams that hit.
    pub hits: usize,
}

/// The beams a check uses of a scan of `n`: all of them up to `max_beams`, else
/// `max_beams` spread evenly, first and last included (numpy's
/// `linspace(0, n - 1, max_beams).round()`: ties to even).
pub fn subsample(n: usize, max_beams: usize) -> Vec<usize> {
    if n <= max_beams {
        return (0..n).collect();
    }
    if max_beams == 0 {
        return Vec::new();
    }
    if max_beams == 1 {
        return vec![0];
    }
    let stop = (n - 1) as f64;
    let step = stop / (max_beams - 1) as f64;
    let mut k: Vec<usize> = (0..max_beams)
        .map(|i| (i as f64 * step).round_ties_even() as usize)
        .collect();
    k[max_beams - 1] = n - 1;
    k
}

/// numpy's pairwise summation of a contiguous float64 array (`np.sum`, `np.mean`): blocks
/// of at most 128 summed with eight accumulators, longer arrays split in halves.
pub fn pairwise_sum(a: &[f64]) -> f64 {
    let n = a.len();
    if n < 8 {
        let mut res = 0.0;
        for v in a {
            res += v;
        }
        res
    } else if n <= 128 {
        let mut r = [0.0f64; 8];
        r.copy_from_slice(&a[..8]);
        let mut i = 8;
        while i < n - (n % 8) {
            for j in 0..8 {
                r[j] += a[i + j];
            }
            i += 8;
        }
        let mut res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        while i < n {
            res += a[i];
            i += 1;
        }
        res
    } else {
        let mut n2 = n / 2;
        n2 -= n2 % 8;
        pairwise_sum(&a[..n2]) + pairwise_sum(&a[n2..])
    }
}

/// The evidence of the scan `points` (robot frame) at `pose`: the beams of
/// [`subsample`]`(points.len(), max_beams)` moved into the map frame, each a hit when its
/// nearest map point (exact k-d tree answer) is closer than `hit_distance`; the residual
/// of a hit is its offset from that point along the point's normal.
pub fn fit_score(
    index: &MapIndex,
    points: &[[f64; 2]],
    pose: Pose2,
    max_beams: usize,
    hit_distance: f64,
) -> FitScore {
    let n_all = points.len();
    if n_all == 0 {
        return FitScore {
            hit: 0.0,
            rms: f64::INFINITY,
            beams: 0,
            hits: 0,
        };
    }
    let (c, s) = (pose.theta.cos(), pose.theta.sin());
    let map = index.points();
    let normals = index.normals();
    let mut r2 = Vec::with_capacity(n_all.min(max_beams.max(1)));
    let mut score = |p: [f64; 2]| {
        let wx = pose.x + c * p[0] - s * p[1];
        let wy = pose.y + s * p[0] + c * p[1];
        let (d2, j) = index.nearest([wx, wy]);
        if d2.sqrt() < hit_distance {
            let (m, u) = (map[j], normals[j]);
            let r = (wx - m[0]) * u[0] + (wy - m[1]) * u[1];
            r2.push(r * r);
        }
    };
    let beams = if n_all > max_beams {
        let k = subsample(n_all, max_beams);
        for &i in &k {
            score(points[i]);
        }
        k.len()
    } else {
        for &p in points {
            score(p);
        }
        n_all
    };
    let hits = r2.len();
    let rms = if hits > 0 {
        (pairwise_sum(&r2) / hits as f64).sqrt()
    } else {
        f64::INFINITY
    };
    FitScore {
        hit: if beams > 0 {
            hits as f64 / beams as f64
        } else {
            0.0
        },
        rms,
        beams,
        hits,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square_room() -> MapIndex {
        // the walls of a 4 m x 4 m room, 5 cm apart, normals pointing inwards
        let mut p = Vec::new();
        let mut nrm = Vec::new();
        for i in 0..=80 {
            let t = -2.0 + 0.05 * i as f64;
            for (q, u) in [
                ([t, -2.0], [0.0, 1.0]),
                ([t, 2.0], [0.0, -1.0]),
                ([-2.0, t], [1.0, 0.0]),
                ([2.0, t], [-1.0, 0.0]),
            ] {
                p.push(q);
                nrm.push(u);
            }
        }
        MapIndex::new(p, Some(nrm)).unwrap()
    }

    /// beams from the room's centre to its walls, `n` of them over a full turn
    fn beams(n: usize, scale: f64) -> Vec<[f64; 2]> {
        (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64 + 0.01;
                let (s, c) = a.sin_cos();
                let r = 2.0 / c.abs().max(s.abs());
                [scale * r * c, scale * r * s]
            })
            .collect()
    }

    #[test]
    fn subsample_spreads_evenly_and_keeps_the_ends() {
        assert_eq!(subsample(5, 120), vec![0, 1, 2, 3, 4]);
        let k = subsample(361, 120);
        assert_eq!(k.len(), 120);
        assert_eq!((k[0], k[119]), (0, 360));
        assert!(k.windows(2).all(|w| w[1] > w[0] && w[1] - w[0] <= 4));
        // 0.5 rounds to even: linspace(0, 2, 5) = 0, 0.5, 1, 1.5, 2 -> 0, 0, 1, 2, 2
        assert_eq!(subsample(3, 5), vec![0, 1, 2]);
        assert_eq!(subsample(9, 3), vec![0, 4, 8]);
        assert_eq!(subsample(5, 3), vec![0, 2, 4]);
    }

    #[test]
    fn pairwise_sum_matches_exact_sums_and_splits_long_arrays() {
        for n in [0usize, 1, 7, 8, 9, 127, 128, 129, 300, 1000] {
            let a: Vec<f64> = (0..n).map(|i| i as f64).collect();
            let exact = (n * n.saturating_sub(1) / 2) as f64;
            assert_eq!(pairwise_sum(&a), exact, "n = {n}");
        }
        // the order matters for inexact terms: added to 1e16 one by one (its spacing is 2)
        // each 1 is lost; the eight accumulators add the ones among themselves first
        let mut a = vec![1.0; 16];
        a[0] = 1e16;
        let sequential = a.iter().fold(0.0, |s, v| s + v);
        assert_eq!(sequential, 1e16);
        assert_eq!(pairwise_sum(&a), 1e16 + 14.0);
    }

    #[test]
    fn the_right_pose_hits_every_beam_and_a_wrong_one_fewer() {
        let idx = square_room();
        let pts = beams(360, 1.0);
        let at = fit_score(&idx, &pts, Pose2::identity(), 120, 0.05);
        assert_eq!(at.beams, 120);
        assert_eq!(at.hits, 120);
        assert_eq!(at.hit, 1.0);
        assert!(at.rms < 1e-9, "rms {}", at.rms);
        // 30 cm off along x: the beams to the side walls still end on them, those to
        // the front and back walls do not
        let off = fit_score(&idx, &pts, Pose2::new(0.3, 0.0, 0.0), 120, 0.05);
        assert!(off.hit < 0.8 && off.hit > 0.2, "hit {}", off.hit);
        // the residual of the hits is along the walls' normals: the side walls' beams
        // are exact, so the RMS stays under the hit distance
        assert!(off.rms < 0.05);
    }

    #[test]
    fn residual_is_the_offset_along_the_normal() {
        let idx = square_room();
        // every beam 2 cm short of its wall: a residual of 2 cm on the walls' normals
        let pts = beams(100, 1.0)
            .into_iter()
            .map(|p| {
                let k = if p[0].abs() > p[1].abs() {
                    (p[0].abs() - 0.02) / p[0].abs()
                } else {
                    (p[1].abs() - 0.02) / p[1].abs()
                };
                [p[0] * k, p[1] * k]
            })
            .collect::<Vec<_>>();
        let at = fit_score(&idx, &pts, Pose2::identity(), 120, 0.1);
        assert_eq!(at.beams, 100);
        assert_eq!(at.hits, 100);
        assert!((at.rms - 0.02).abs() < 1e-12, "rms {}", at.rms);
    }

    #[test]
    fn no_beams_and_no_hits() {
        let idx = square_room();
        let none = fit_score(&idx, &[], Pose2::identity(), 120, 0.05);
        assert_eq!((none.beams, none.hits, none.hit), (0, 0, 0.0));
        assert!(none.rms.is_infinite());
        // half-length beams end in the middle of the room
        let miss = fit_score(&idx, &beams(50, 0.5), Pose2::identity(), 120, 0.05);
        assert_eq!((miss.beams, miss.hits, miss.hit), (50, 0, 0.0));
        assert!(miss.rms.is_infinite());
    }
}
