//! The cheap local checks of the verified start of [`crate::icp::align`], tried before the
//! window search:
//!
//! * [`slide_candidates`]: in a corridor or an aisle a fit is free along one axis, and ICP
//!   from a start a few decimetres off can settle one door frame or rack upright along it.
//!   A 1-D scan of the likelihood field along that axis (±`window_position`, half-cell
//!   steps) finds the other places along the corridor that explain the scan about as well;
//!   the caller refines them by ICP and keeps the best. A few hundred field look-ups instead
//!   of the window's tens of thousands.
//! * [`heading_prior`]: the heading at which the scan's wall directions line up with the
//!   map's (a correlation of two histograms of line directions modulo π, 1° bins, over
//!   ±`window_heading` around the start): a second ICP start when the first fit kept most
//!   of a large heading error (racks and people pull the first iterations to wrong walls).
//!   The map's histogram ([`map_directions`]) is built once per map
//!   (`MapIndex::line_directions`).

use std::f64::consts::PI;

use crate::icp::window::{add_exp, map_distance, NEGLIGIBLE_EXP};
use crate::index::MapIndex;
use crate::se2::{wrap_angle, Pose2};

/// Bins of the direction histograms over [0, π): 1° each.
pub(crate) const DIRECTION_BINS: usize = 180;
/// Half-width (bins) of the triangular kernel that smooths the histograms.
const SMOOTH_BINS: usize = 2;
/// A scan line piece spans 4, 8 or 16 beam steps (see [`PIECE_HALF_SPANS`]); it counts when
/// that chord is this long (m) at least (shorter: the range noise dominates its direction) ...
const MIN_CHORD: f64 = 0.08;
/// ... at most this long (longer: a depth jump, not a wall) ...
const MAX_CHORD: f64 = 0.6;
/// ... and its middle points lie within this fraction of its length of the chord.
const MAX_BEND: f64 = 0.08;
/// Half-spans (beam steps either side of a point) a line piece may have, shortest first:
/// the first whose chord is at least [`MIN_CHORD`] long is the point's piece.
const PIECE_HALF_SPANS: [usize; 3] = [2, 4, 8];
/// The heading prior needs at least this many line pieces.
const MIN_PIECES: usize = 12;
/// Candidates along the corridor are kept when they score at least this fraction of the
/// best place along it ...
pub(crate) const SLIDE_KEEP: f64 = 0.85;
/// ... and at most this many, best first ...
pub(crate) const SLIDE_CANDIDATES: usize = 3;
/// ... at least this far (m) from the fit itself.
const SLIDE_MIN_OFFSET: f64 = 0.12;

/// Triangular smoothing of a circular histogram, normalised to sum 1 (all zeros stays so).
fn smooth(h: &[f64]) -> Vec<f32> {
    let n = h.len();
    // the wrap below folds at most one extra turn: right only when n > SMOOTH_BINS
    debug_assert!(n == 0 || n > SMOOTH_BINS);
    let w: [f64; 2 * SMOOTH_BINS + 1] =
        std::array::from_fn(|d| (SMOOTH_BINS + 1 - SMOOTH_BINS.abs_diff(d)) as f64);
    let mut out = vec![0.0f64; n];
    for (i, o) in out.iter_mut().enumerate() {
        if i >= SMOOTH_BINS && i + SMOOTH_BINS < n {
            // away from the ends: no wrap (the same terms, added in the same order)
            for (d, &wd) in w.iter().enumerate() {
                *o += wd * h[i + d - SMOOTH_BINS];
            }
            continue;
        }
        for (d, &wd) in w.iter().enumerate() {
            // (i + n + d − SMOOTH_BINS) mod n, without the division
            let k = i + n + d - SMOOTH_BINS;
            *o += wd
                * h[if k >= 2 * n {
                    k - 2 * n
                } else if k >= n {
                    k - n
                } else {
                    k
                }];
        }
    }
    let total: f64 = out.iter().sum();
    if total > 0.0 {
        out.iter_mut().for_each(|v| *v /= total);
    }
    out.into_iter().map(|v| v as f32).collect()
}

#[inline]
fn bin_of(angle: f64) -> usize {
    // `angle.rem_euclid(PI)`, without the remainder's division when |angle| < π (whose
    // remainder is the angle itself: the same value)
    let r = if angle.abs() < PI { angle } else { angle % PI };
    let a = if r < 0.0 { r + PI } else { r };
    ((a / PI * DIRECTION_BINS as f64) as usize).min(DIRECTION_BINS - 1)
}

/// The map's histogram of line directions (the direction at each map point: its normal
/// turned by 90°), smoothed and normalised.
pub(crate) fn map_directions(normals: &[[f64; 2]]) -> Vec<f32> {
    let mut h = vec![0.0f64; DIRECTION_BINS];
    for n in normals {
        if n[0].is_finite() && n[1].is_finite() && (n[0] != 0.0 || n[1] != 0.0) {
            h[bin_of(n[1].atan2(n[0]) + 0.5 * PI)] += 1.0;
        }
    }
    smooth(&h)
}

/// The scan's histogram of line directions in the sensor frame: the points in bearing
/// order (so not dependent on the order of the array), and for each the chord from the
/// point two beams before to the one two after (four or eight when that chord is shorter
/// than [`MIN_CHORD`]), when it is a straight wall piece; each piece weighted by its length. `None` with fewer than [`MIN_PIECES`] pieces.
pub(crate) fn scan_directions(scan: &[[f64; 2]]) -> Option<Vec<f32>> {
    let mut pts: Vec<[f64; 2]> = Vec::with_capacity(scan.len());
    pts.extend(scan.iter().filter(|p| {
        p[0].is_finite() && p[1].is_finite() && p[0] * p[0] + p[1] * p[1] > 0.05 * 0.05
    }));
    if pts.len() < 5 {
        return None;
    }
    // bearing order, keyed by the polynomial arctangent (a key per point is a total
    // order; comparing by half-plane and cross product is not: bearings 0 and π tie, and
    // the products of extreme coordinates round); a scan in beam order is sorted already,
    // which the sort sees in one pass
    let mut keyed: Vec<(f64, [f64; 2])> =
        pts.iter().map(|p| (approx_atan2(p[1], p[0]), *p)).collect();
    keyed.sort_unstable_by(|(ka, a), (kb, b)| {
        ka.total_cmp(kb)
            .then(a[0].total_cmp(&b[0]))
            .then(a[1].total_cmp(&b[1]))
    });
    pts.clear();
    pts.extend(keyed.into_iter().map(|(_, p)| p));
    let mut h = vec![0.0f64; DIRECTION_BINS];
    let mut pieces = 0usize;
    let n = pts.len();
    for i in 2..n.saturating_sub(2) {
        // the shortest span (4, 8 or 16 beam steps about the point) whose chord is long
        // enough: a wall 1-2 m away gives 4-step chords of 3-7 cm, whose direction the
        // range noise sets (in the clinic's 3 m rooms most walls are that near)
        for half in PIECE_HALF_SPANS {
            if i < half || i + half >= n {
                break;
            }
            let (a, b) = (pts[i - half], pts[i + half]);
            let c = [b[0] - a[0], b[1] - a[1]];
            let len = (c[0] * c[0] + c[1] * c[1]).sqrt();
            if len < MIN_CHORD {
                continue;
            }
            if len > MAX_CHORD {
                break;
            }
            let q = half / 2;
            let bend = MAX_BEND * len;
            let straight = [pts[i - q], pts[i], pts[i + q]].iter().all(|m| {
                let area = (c[0] * (m[1] - a[1]) - c[1] * (m[0] - a[0])).abs();
                within_bend(area, len, bend)
            });
            if straight {
                h[bin_of(approx_atan2(c[1], c[0]))] += len;
                pieces += 1;
            }
            break;
        }
    }
    (pieces >= MIN_PIECES).then(|| smooth(&h))
}

/// `area / len <= bend` (a middle point's offset from a chord of length `len` > 0 against
/// the bend allowed, all finite and non-negative), as computed in floating point, mostly
/// without the division: away from the border (a relative 1e-12, far beyond the rounding
/// of the quotient and of the product here) the product `bend · len` decides it; at the
/// border the quotient itself.
#[inline(always)]
fn within_bend(area: f64, len: f64, bend: f64) -> bool {
    let lim = bend * len;
    if area <= lim * (1.0 - 1e-12) {
        true
    } else if area >= lim * (1.0 + 1e-12) {
        false
    } else {
        area / len <= bend
    }
}

/// `atan2(y, x)` to about 1e-5 rad (a polynomial for the arctangent on [-1, 1],
/// Abramowitz & Stegun 4.4.49): the histograms' bins are 1° wide, and the exact one is
/// a good part of the histogram's cost.
fn approx_atan2(y: f64, x: f64) -> f64 {
    let (ax, ay) = (x.abs(), y.abs());
    if ax == 0.0 && ay == 0.0 {
        return 0.0;
    }
    let z = ax.min(ay) / ax.max(ay);
    let z2 = z * z;
    let mut a = z
        * (0.999_866
            + z2 * (-0.330_299_5 + z2 * (0.180_141 + z2 * (-0.085_133 + z2 * 0.020_835_1))));
    if ay > ax {
        a = 0.5 * PI - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

/// The heading within ±`half_range` of `center` at which the scan's directions `scan_h`
/// best match the map's `map_h` (correlation on 1° shifts, refined by a parabola through
/// the peak); `None` when nothing correlates.
pub(crate) fn heading_prior(
    scan_h: &[f32],
    map_h: &[f32],
    center: f64,
    half_range: f64,
) -> Option<f64> {
    let n = DIRECTION_BINS as i64;
    let step = PI / DIRECTION_BINS as f64;
    let c0 = (center / step).round() as i64;
    let k = (half_range / step).ceil() as i64;
    // the correlation at the shifts c0 − k − 1, …, c0 + k + 1: for shift s, the sum over
    // the scan's non-empty bins b (a few walls' directions), in ascending order, of
    // scan[b] · map[(b + s) mod n]. Computed bin by bin for all shifts at once (each
    // shift's sum still adds its terms in the order of the bins: the same sums, in a
    // loop over contiguous shifts that the compiler vectorises), on the map's histogram
    // repeated so that b + s needs no modulo.
    let shifts = (2 * k + 3) as usize;
    let s0 = (c0 - k - 1).rem_euclid(n) as usize;
    let nu = n as usize;
    let reps = (nu - 1 + s0 + shifts).div_ceil(nu);
    let repeated: Vec<f64> = (0..reps)
        .flat_map(|_| map_h.iter().map(|&v| v as f64))
        .collect();
    let mut vals = vec![0.0f64; shifts];
    for (b, &v) in scan_h.iter().enumerate() {
        if v == 0.0 {
            continue;
        }
        let v = v as f64;
        let row = &repeated[b + s0..b + s0 + shifts];
        for (acc, &m) in vals.iter_mut().zip(row) {
            *acc += v * m;
        }
    }
    let (mut bi, mut bv) = (0usize, 0.0f64);
    for (i, &v) in vals.iter().enumerate().skip(1).take(vals.len() - 2) {
        if v > bv {
            (bi, bv) = (i, v);
        }
    }
    if !(bv > 0.0) {
        return None;
    }
    let (l, r) = (vals[bi - 1], vals[bi + 1]);
    let den = l - 2.0 * bv + r;
    let frac = if den < 0.0 {
        (0.5 * (l - r) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    let shift = (c0 + bi as i64 - k - 1) as f64 + frac;
    Some(wrap_angle(shift * step))
}

/// Step (m) of the look along the corridor.
pub(crate) const SLIDE_STEP: f64 = 0.04;

/// Places along the unit map-frame direction `dir` from `pose` (same heading), at offsets
/// in [`t_lo`, `t_hi`] m every [`SLIDE_STEP`], where the sensor-frame points `sub` score at
/// least [`SLIDE_KEEP`] of the best place (the best local maximum) and lie at least [`SLIDE_MIN_OFFSET`] from `pose`:
/// local maxima, best first, at most [`SLIDE_CANDIDATES`]. The score: the mean Gaussian
/// likelihood of the points' distances to the map (point-to-line near a wall; σ the
/// expected noise widened by half a step), as [`crate::icp::assess`] scores a pose — the
/// likelihood field's 10 cm cells are too coarse to tell the places along a corridor
/// apart (a few door jambs and furniture ends are all that differ).
pub(crate) fn slide_candidates(
    index: &MapIndex,
    sub: &[[f64; 2]],
    pose: Pose2,
    dir: [f64; 2],
    range: (f64, f64),
    expected_noise: f64,
) -> Vec<Pose2> {
    slide_candidates_of(index, sub, None, pose, dir, range, expected_noise).0
}

/// [`slide_candidates`] of `pts` and, with `part` (a flag per point), of the flagged
/// points too (in their order in `pts`), from one look-up per point and offset: the same
/// candidates as two calls, at the cost of one (the sums of each offset run over the
/// points in their order either way). The second list is empty without `part`.
pub(crate) fn slide_candidates_of(
    index: &MapIndex,
    pts: &[[f64; 2]],
    part: Option<&[bool]>,
    pose: Pose2,
    dir: [f64; 2],
    (t_lo, t_hi): (f64, f64),
    expected_noise: f64,
) -> (Vec<Pose2>, Vec<Pose2>) {
    let (k_lo, k_hi) = (
        (t_lo / SLIDE_STEP).ceil() as i64,
        (t_hi / SLIDE_STEP).floor() as i64,
    );
    let in_part = |i: usize| part.is_some_and(|m| m[i]);
    let part_len = (0..pts.len()).filter(|&i| in_part(i)).count();
    if k_hi <= k_lo || pts.is_empty() {
        return (Vec::new(), Vec::new());
    }
    let normals = index.normals();
    let sigma = expected_noise + 0.5 * SLIDE_STEP;
    let band = 3.0 * sigma;
    let near = 2.0 * index.spacing() + band;
    let inv2s2 = 1.0 / (2.0 * sigma * sigma);
    let offsets: Vec<f64> = (k_lo..=k_hi).map(|i| i as f64 * SLIDE_STEP).collect();
    // point by point, every offset of one point in turn (its look-ups lie along one
    // short line: the same few grid tiles), each offset's sums in the points' order
    let mut scores = vec![0.0f64; offsets.len()];
    let mut part_scores = vec![0.0f64; if part_len > 0 { offsets.len() } else { 0 }];
    for (i, p) in pts.iter().enumerate() {
        let q = pose.transform(*p);
        let flagged = in_part(i);
        for (k, &t) in offsets.iter().enumerate() {
            let e = map_distance(
                index,
                normals,
                [q[0] + t * dir[0], q[1] + t * dir[1]],
                near * near,
            );
            // the term is skipped only where it cannot change the sums (see `add_exp`)
            let x = -e * e * inv2s2;
            if flagged {
                if !(x < NEGLIGIBLE_EXP && scores[k] >= 1.0 && part_scores[k] >= 1.0) {
                    let v = x.exp();
                    scores[k] += v;
                    part_scores[k] += v;
                }
            } else {
                scores[k] = add_exp(scores[k], x);
            }
        }
    }
    let all = peaks_of(&scores, k_lo, pose, dir);
    let some = if part_len > 0 {
        peaks_of(&part_scores, k_lo, pose, dir)
    } else {
        Vec::new()
    };
    (all, some)
}

/// The candidates of [`slide_candidates`] from the scores of the offsets `k_lo`, `k_lo` + 1, …
/// (× [`SLIDE_STEP`]).
fn peaks_of(scores: &[f64], k_lo: i64, pose: Pose2, dir: [f64; 2]) -> Vec<Pose2> {
    let last = scores.len() - 1;
    // a place is a peak of its neighbourhood of ±`SLIDE_MIN_OFFSET` (the range noise and
    // people make ripples a step or two apart on the flank of one place; the places a fit
    // can settle at are door frames and rack uprights a metre or more apart)
    let nms = ((SLIDE_MIN_OFFSET / SLIDE_STEP).round() as usize).max(1);
    let peak = |i: usize| {
        let s = scores[i];
        s > 0.0
            && i > 0
            && i < last
            && scores[i.saturating_sub(nms)..i].iter().all(|&o| s >= o)
            && scores[i + 1..(i + 1 + nms).min(last + 1)]
                .iter()
                .all(|&o| s > o)
    };
    // the best place: the best peak (a score still rising at the range's end is a place
    // beyond it, which would otherwise hold every place inside below `SLIDE_KEEP`)
    let best = (0..=last)
        .filter(|&i| peak(i))
        .map(|i| scores[i])
        .fold(0.0, f64::max);
    let keep = SLIDE_KEEP * best;
    let mut peaks: Vec<(f64, i64)> = (0..=last)
        .filter(|&i| {
            let t = (i as i64 + k_lo) as f64 * SLIDE_STEP;
            scores[i] >= keep && t.abs() >= SLIDE_MIN_OFFSET && peak(i)
        })
        .map(|i| (scores[i], i as i64 + k_lo))
        .collect();
    // best first; ties nearest the fit
    peaks.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.abs().cmp(&b.1.abs())));
    peaks
        .into_iter()
        .take(SLIDE_CANDIDATES)
        .map(|(_, i)| {
            let t = i as f64 * SLIDE_STEP;
            Pose2::new(pose.x + t * dir[0], pose.y + t * dir[1], pose.theta)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit::{make_scan, rectangle, sample_segments, Rng};

    fn deg(d: f64) -> f64 {
        d.to_radians()
    }

    #[test]
    fn the_heading_prior_finds_a_turned_room() {
        // a room with a diagonal wall; the scan seen at 0.4 rad, the start 20° off
        let mut segs = rectangle(8.0, 5.0);
        segs.push([1.0, 1.0, 3.0, 2.5]);
        let (_, n) = sample_segments(&segs, 0.025);
        let map_h = map_directions(&n);
        let truth = Pose2::new(4.0, 3.0, 0.4);
        let scan = make_scan(&segs, truth, 361, 30.0, 0.01, 0.0, &mut Rng::new(3));
        let scan_h = scan_directions(&scan).expect("a room has walls");
        let th = heading_prior(&scan_h, &map_h, 0.4 + deg(20.0), deg(30.0)).unwrap();
        assert!(wrap_angle(th - 0.4).abs() < deg(1.5), "{}", th.to_degrees());
    }

    #[test]
    fn the_bend_test_without_division_decides_as_the_quotient() {
        // random values and values at the border (quotients one ulp either side)
        let mut rng = Rng::new(11);
        for k in 0..200_000 {
            let len = rng.range(0.08, 0.6);
            let bend = 0.08 * len;
            let area = if k % 2 == 0 {
                rng.range(0.0, 2.0 * bend * len)
            } else {
                let q = bend * len / len;
                let q = match k % 6 {
                    1 => q,
                    3 => f64::from_bits(q.to_bits() + 1),
                    _ => f64::from_bits(q.to_bits() - 1),
                };
                q * len
            };
            assert_eq!(
                within_bend(area, len, bend),
                area / len <= bend,
                "area {area:e}, len {len}"
            );
        }
    }

    #[test]
    fn the_approximate_arctangent_is_within_a_thousandth_of_a_degree() {
        let mut worst = 0.0f64;
        for k in 0..3600 {
            let t = (k as f64 / 10.0 - 180.0).to_radians();
            for r in [1e-3, 0.7, 5.0] {
                let (y, x) = (r * t.sin(), r * t.cos());
                worst = worst.max(wrap_angle(approx_atan2(y, x) - y.atan2(x)).abs());
            }
        }
        assert!(worst < 1e-3f64.to_radians(), "worst error {worst} rad");
    }

    #[test]
    fn points_on_the_axis_and_far_away_sort_without_panic_in_any_order() {
        // bearings 0 and π (y = 0 on both sides), a wall, and coordinates whose cross
        // products overflow: the sort's order must be total (a comparator by half-plane and
        // cross product is not, and the standard sort panics on it)
        let mut pts: Vec<[f64; 2]> = Vec::new();
        for k in 0..60 {
            let v = 0.5 + 0.1 * k as f64;
            pts.extend([[v, 0.0], [-v, 0.0], [0.0, v], [3.0, -2.0 + 0.07 * k as f64]]);
        }
        pts.extend([[1e300, 1e300], [-1e300, 1e-300], [1e300, -1e300]]);
        let mut rng = Rng::new(3);
        let base = scan_directions(&pts);
        for _ in 0..20 {
            let mut shuffled = pts.clone();
            for i in (1..shuffled.len()).rev() {
                let j = (rng.range(0.0, (i + 1) as f64) as usize).min(i);
                shuffled.swap(i, j);
            }
            assert_eq!(scan_directions(&shuffled), base);
        }
    }

    #[test]
    fn scan_directions_do_not_depend_on_the_point_order() {
        let segs = rectangle(8.0, 5.0);
        let scan = make_scan(
            &segs,
            Pose2::new(3.0, 2.0, 0.3),
            361,
            30.0,
            0.01,
            0.2,
            &mut Rng::new(9),
        );
        let mut rev = scan.clone();
        rev.reverse();
        rev.rotate_left(77);
        assert_eq!(scan_directions(&scan), scan_directions(&rev));
    }

    #[test]
    fn too_few_wall_pieces_give_no_prior() {
        // scattered points: no straight pieces
        let mut rng = Rng::new(4);
        let scan: Vec<[f64; 2]> = (0..40)
            .map(|_| [rng.range(1.0, 9.0), rng.range(-4.0, 4.0)])
            .collect();
        assert_eq!(scan_directions(&scan), None);
    }

    /// a 20 m corridor, 2 m wide, with door frames (cross walls with 1 m openings) every 4 m
    fn door_corridor() -> Vec<crate::raycast::Segment> {
        let mut segs = rectangle(20.0, 2.0);
        for x in [4.0, 8.0, 12.0, 16.0] {
            segs.push([x, 0.0, x, 0.5]);
            segs.push([x, 1.5, x, 2.0]);
        }
        segs
    }

    #[test]
    fn a_slide_along_a_corridor_is_found() {
        // a 20 m corridor, 2 m wide, with door frames (cross walls with 1 m openings)
        // every 4 m: a fit 0.4 m along the corridor from the truth
        let segs = door_corridor();
        let (p, n) = sample_segments(&segs, 0.025);
        let idx = MapIndex::new(p, Some(n)).unwrap();
        let truth = Pose2::new(9.3, 1.0, 0.0);
        let scan = make_scan(&segs, truth, 361, 8.0, 0.01, 0.0, &mut Rng::new(2));
        let slid = Pose2::new(9.7, 1.0, 0.0);
        let c = slide_candidates(&idx, &scan, slid, [1.0, 0.0], (-1.0, 1.0), 0.02);
        assert!(!c.is_empty());
        assert!(
            (c[0].x - truth.x).abs() <= 0.5 * SLIDE_STEP + 1e-9,
            "{:?}",
            c
        );
        assert_eq!((c[0].y, c[0].theta), (slid.y, slid.theta));
    }

    #[test]
    fn one_pass_over_points_and_their_part_gives_the_two_lists() {
        // the corridor above: the candidates of the points and of a flagged part of them
        // (every third point) from one pass are those of two separate calls, bit for bit
        let segs = door_corridor();
        let (p, n) = sample_segments(&segs, 0.025);
        let idx = MapIndex::new(p, Some(n))
            .unwrap()
            .with_cache(Some(crate::index::DEFAULT_CACHE_RESOLUTION))
            .unwrap();
        let truth = Pose2::new(9.3, 1.0, 0.0);
        let scan = make_scan(&segs, truth, 361, 8.0, 0.01, 0.0, &mut Rng::new(5));
        let flags: Vec<bool> = (0..scan.len()).map(|i| i % 3 == 0).collect();
        let part: Vec<[f64; 2]> = scan
            .iter()
            .zip(&flags)
            .filter(|(_, &f)| f)
            .map(|(p, _)| *p)
            .collect();
        for slid in [Pose2::new(9.7, 1.0, 0.0), Pose2::new(8.1, 1.02, 0.01)] {
            let range = (-1.25, 1.25);
            let (all, some) =
                slide_candidates_of(&idx, &scan, Some(&flags), slid, [1.0, 0.0], range, 0.02);
            assert!(!all.is_empty() && !some.is_empty());
            assert_eq!(
                all,
                slide_candidates(&idx, &scan, slid, [1.0, 0.0], range, 0.02)
            );
            assert_eq!(
                some,
                slide_candidates(&idx, &part, slid, [1.0, 0.0], range, 0.02)
            );
        }
    }
}
