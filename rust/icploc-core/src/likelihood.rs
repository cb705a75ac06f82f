//! The likelihood field of a map and its max-pooled pyramid: the scoring grid of the
//! correlative (branch-and-bound) searches — the global search ([`crate::global`]) and
//! the local window search of [`crate::icp::align`].
//!
//! * `dist`: distance from each cell centre to the closest map point (k-d tree), f32;
//! * `pooled[0]`: the likelihood `255·exp(−d²/2σ²)` as u8;
//! * `pooled[h]`: at cell (i, j), the maximum of `pooled[0]` over the 2ʰ × 2ʰ window
//!   starting there — so the sum of `pooled[h]` under a scan's points is an exact upper
//!   bound of the score of every translation in that window.

use rayon::prelude::*;

use crate::error::{IcpError, Result};
use crate::index::MapIndex;

/// Grids larger than this many cells are refused (memory: ~ 8 bytes per cell per level).
pub const MAX_CELLS: usize = 40_000_000;

/// The field the window search of `icp()` uses, built lazily once per [`MapIndex`]
/// ([`MapIndex::likelihood_field`]): 10 cm cells (at 5 cm the large-start p95 was 1.3–1.9 times
/// as long for the same success on the scenario families: the ICP refinement starts within
/// half a cell of its optimum either way), σ = 0.1 m, 6 pooled levels.
pub const WINDOW_RESOLUTION: f64 = 0.1;
pub const WINDOW_SIGMA: f64 = 0.1;
pub const WINDOW_LEVELS: usize = 6;
/// The window search's field holds at most this many cells per level (~ 90 MB in all).
pub const WINDOW_MAX_CELLS: usize = 1 << 23;

/// hook (speed2): the version of the distances [`LikelihoodField::build`] computes; bump it
/// when they change (the likelihood-field cache of `icploc.maps.cache` names it).
pub const FIELD_VERSION: u32 = 1;

/// A likelihood grid over a map's bounds with its max-pooled pyramid.
#[derive(Clone)]
pub struct LikelihoodField {
    pub(crate) res: f64,
    pub(crate) x0: f64,
    pub(crate) y0: f64,
    pub(crate) w: usize,
    pub(crate) h: usize,
    /// Distance (m) from each cell centre to the nearest map point.
    pub(crate) dist: Vec<f32>,
    /// Pooled likelihood, level 0 = the likelihood itself.
    pub(crate) pooled: Vec<Vec<u8>>,
}

impl std::fmt::Debug for LikelihoodField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LikelihoodField")
            .field("resolution", &self.res)
            .field("origin", &(self.x0, self.y0))
            .field("cells", &(self.w, self.h))
            .field("levels", &self.pooled.len())
            .finish()
    }
}

impl LikelihoodField {
    /// Build the field of `index` at `resolution` m per cell, likelihood σ `sigma`, with
    /// `levels` pooled levels above the base. Refuses grids of more than [`MAX_CELLS`].
    pub fn build(index: &MapIndex, resolution: f64, sigma: f64, levels: usize) -> Result<Self> {
        let (x0, y0, w, h) = Self::grid(index, resolution)?;
        let dist: Vec<f32> = (0..w * h)
            .into_par_iter()
            .with_min_len(1024)
            .map(|c| {
                let (i, j) = (c % w, c / w);
                let q = [
                    x0 + (i as f64 + 0.5) * resolution,
                    y0 + (j as f64 + 0.5) * resolution,
                ];
                index.nearest(q).0.sqrt() as f32
            })
            .collect();
        Ok(Self::finish(resolution, x0, y0, w, h, dist, sigma, levels))
    }

    /// hook (speed2, the likelihood-field cache): the field `build` gives for `index` at
    /// `resolution` from the distances (`distances()`) a previous `build` of the same map
    /// computed, without the nearest-point queries. Refused when their number is not the
    /// grid's cell count.
    pub fn from_distances(
        index: &MapIndex,
        resolution: f64,
        sigma: f64,
        levels: usize,
        dist: Vec<f32>,
    ) -> Result<Self> {
        let (x0, y0, w, h) = Self::grid(index, resolution)?;
        if dist.len() != w * h {
            return Err(IcpError::InvalidInput {
                what: "distances".into(),
                reason: format!("{} values for a {w} x {h} grid", dist.len()),
            });
        }
        Ok(Self::finish(resolution, x0, y0, w, h, dist, sigma, levels))
    }

    /// The distance (m) of every cell centre to the nearest map point, row by row.
    pub fn distances(&self) -> &[f32] {
        &self.dist
    }

    /// (x0, y0, width, height) of the grid over `index`'s bounds at `resolution`.
    fn grid(index: &MapIndex, resolution: f64) -> Result<(f64, f64, usize, usize)> {
        if resolution <= 0.0 || !resolution.is_finite() {
            return Err(IcpError::InvalidInput {
                what: "resolution".into(),
                reason: format!("must be positive and finite, got {resolution}"),
            });
        }
        let [xmin, ymin, xmax, ymax] = index.bounds();
        let wf = ((xmax - xmin) / resolution).floor() + 1.0;
        let hf = ((ymax - ymin) / resolution).floor() + 1.0;
        if !(wf.is_finite() && hf.is_finite()) || wf * hf > MAX_CELLS as f64 {
            return Err(IcpError::GridTooLarge {
                width: xmax - xmin,
                height: ymax - ymin,
                resolution,
                cells: wf * hf,
                max: MAX_CELLS,
            });
        }
        Ok((xmin, ymin, wf as usize, hf as usize))
    }

    /// The likelihood and its pyramid over the distances `dist`.
    #[allow(clippy::too_many_arguments)]
    fn finish(
        resolution: f64,
        x0: f64,
        y0: f64,
        w: usize,
        h: usize,
        dist: Vec<f32>,
        sigma: f64,
        levels: usize,
    ) -> Self {
        let inv2s2 = 1.0 / (2.0 * sigma * sigma);
        // in parallel (a 5 cm field of a large map has ~25 M cells), and without the
        // exponential where it rounds to 0 anyway: the same bytes
        let base: Vec<u8> = dist
            .par_iter()
            .with_min_len(4096)
            .map(|&d| likelihood_u8(d, inv2s2))
            .collect();
        let mut pooled = vec![base];
        for lvl in 1..=levels {
            let next = pool(&pooled[lvl - 1], w, h, 1usize << (lvl - 1), u8::max);
            pooled.push(next);
        }
        Self {
            res: resolution,
            x0,
            y0,
            w,
            h,
            dist,
            pooled,
        }
    }

    /// The field `icp()`'s window search uses for `index`: [`WINDOW_RESOLUTION`], or 2 or 4
    /// times it when the map's bounds need more than [`WINDOW_MAX_CELLS`] cells;
    /// `None` when even 4 times does not fit (the window search is then skipped).
    pub(crate) fn for_window(index: &MapIndex) -> Option<Self> {
        let [x0, y0, x1, y1] = index.bounds();
        (0..3)
            .map(|k| WINDOW_RESOLUTION * (1 << k) as f64)
            .find(|res| {
                let cells = (((x1 - x0) / res).floor() + 1.0) * (((y1 - y0) / res).floor() + 1.0);
                cells.is_finite() && cells <= WINDOW_MAX_CELLS as f64
            })
            .and_then(|res| Self::build(index, res, WINDOW_SIGMA.max(res), WINDOW_LEVELS).ok())
    }

    pub fn resolution(&self) -> f64 {
        self.res
    }

    /// Grid size in cells (width, height).
    pub fn shape(&self) -> (usize, usize) {
        (self.w, self.h)
    }

    /// Number of pooled levels above the base.
    pub fn levels(&self) -> usize {
        self.pooled.len() - 1
    }

    /// Distance (m) from `p` to the map as stored in the grid (nearest cell); `None`
    /// outside the grid.
    #[inline]
    pub fn distance_at(&self, p: [f64; 2]) -> Option<f64> {
        let x = (p[0] - self.x0) / self.res;
        let y = (p[1] - self.y0) / self.res;
        // for x ≥ 0 the truncation is ⌊x⌋ (`f64::floor` is a libm call on baseline x86-64,
        // and this is the see-through check's inner loop); NaN, negatives and values beyond
        // the grid fail the test, and the rest truncate without a saturating cast's tests
        if x >= 0.0 && y >= 0.0 && x < self.w as f64 && y < self.h as f64 {
            // SAFETY: 0 ≤ x < w and 0 ≤ y < h (so finite and below 2⁶³): their
            // truncations are representable, and below w and h (integers)
            let (xi, yi) = unsafe {
                (
                    x.to_int_unchecked::<i64>() as usize,
                    y.to_int_unchecked::<i64>() as usize,
                )
            };
            Some(self.dist[yi * self.w + xi] as f64)
        } else {
            None
        }
    }

    /// Clearance (m) of `p` from the map: the stored distance inside the grid; outside it
    /// the distance to the grid's rectangle, a lower bound (the map lies inside it). A
    /// pose beyond the map's bounds — a robot standing outside the mapped area, or looking
    /// at a small map from afar — is still a pose.
    pub fn clearance_at(&self, p: [f64; 2]) -> f64 {
        self.distance_at(p).unwrap_or_else(|| {
            let x1 = self.x0 + self.w as f64 * self.res;
            let y1 = self.y0 + self.h as f64 * self.res;
            let dx = (self.x0 - p[0]).max(p[0] - x1).max(0.0);
            let dy = (self.y0 - p[1]).max(p[1] - y1).max(0.0);
            dx.hypot(dy)
        })
    }

    /// The cell (i, j) of a map-frame point (may lie outside the grid).
    #[inline]
    pub(crate) fn cell(&self, p: [f64; 2]) -> (i32, i32) {
        let i = ((p[0] - self.x0) / self.res).floor();
        let j = ((p[1] - self.y0) / self.res).floor();
        (
            i.clamp(i32::MIN as f64 / 4.0, i32::MAX as f64 / 4.0) as i32,
            j.clamp(i32::MIN as f64 / 4.0, i32::MAX as f64 / 4.0) as i32,
        )
    }

    /// Sum of pooled level `level` under the cells `offs` shifted by (i, j): at level 0 the
    /// exact score of that translation, above it an upper bound of every translation in
    /// the 2^level × 2^level window starting there.
    #[inline]
    pub(crate) fn sum(&self, level: usize, offs: &[(i32, i32)], i: i32, j: i32) -> u32 {
        let g = &self.pooled[level];
        let (w, h) = (self.w as i32, self.h as i32);
        // a window starting left of / below the grid: the window at 0 covers its in-grid
        // part (and more), so it still bounds it
        let lo = 1 - (1i32 << level);
        let mut s = 0u32;
        for &(ox, oy) in offs {
            let (x, y) = (i + ox, j + oy);
            if x >= lo && y >= lo && x < w && y < h {
                s += g[(y.max(0) * w + x.max(0)) as usize] as u32;
            }
        }
        s
    }
}

/// `255·exp(−d²·inv2s2)` rounded to a byte: the plain formula `likelihood_u8` keeps.
#[cfg(test)]
fn likelihood_u8_exact(d: f32, inv2s2: f64) -> u8 {
    let d = d as f64;
    (255.0 * (-d * d * inv2s2).exp()).round() as u8
}

/// Beyond this exponent `255·exp(−x)` is below 0.4922 and rounds to 0
/// (`ln 510 ≈ 6.2344`).
const ZERO_EXPONENT: f64 = 6.25;

/// [`likelihood_u8_exact`] without the exponential where the byte is 0 (most of a large
/// map's cells lie far from every wall): the same value for every `d`.
#[inline]
fn likelihood_u8(d: f32, inv2s2: f64) -> u8 {
    let d = d as f64;
    let x = d * d * inv2s2;
    if x > ZERO_EXPONENT {
        0
    } else {
        (255.0 * (-x).exp()).round() as u8
    }
}

/// One max-pooling step: cell c takes `op` over c and its neighbours `s` cells right, up
/// and diagonally (where inside the grid). `op` must be commutative and associative (max,
/// or): row by row, the row `s` above first, then the cell `s` to the right (in place,
/// left to right: the cell read is not written yet), so the inner loops vectorise.
pub(crate) fn pool<T: Copy + Send + Sync>(
    prev: &[T],
    w: usize,
    h: usize,
    s: usize,
    op: impl Fn(T, T) -> T + Sync + Send,
) -> Vec<T> {
    let mut out = prev.to_vec();
    if w == 0 {
        return out;
    }
    out.par_chunks_mut(w)
        .with_min_len((4096 / w).max(1))
        .enumerate()
        .for_each(|(j, row)| {
            if j + s < h {
                let up = &prev[(j + s) * w..(j + s + 1) * w];
                for (m, &u) in row.iter_mut().zip(up) {
                    *m = op(*m, u);
                }
            }
            for i in 0..w.saturating_sub(s) {
                row[i] = op(row[i], row[i + s]);
            }
        });
    out
}

/// The cell-by-cell form of [`pool`] (the reference its tests compare with).
#[cfg(test)]
fn pool_plain<T: Copy>(prev: &[T], w: usize, h: usize, s: usize, op: fn(T, T) -> T) -> Vec<T> {
    (0..w * h)
        .map(|c| {
            let (i, j) = (c % w, c / w);
            let mut m = prev[c];
            if i + s < w {
                m = op(m, prev[c + s]);
            }
            if j + s < h {
                m = op(m, prev[c + s * w]);
                if i + s < w {
                    m = op(m, prev[c + s * w + s]);
                }
            }
            m
        })
        .collect()
}

#[cfg(test)]
mod grid_bound_tests {
    use super::*;

    #[test]
    fn a_field_from_its_distances_is_the_built_field() {
        let pts: Vec<[f64; 2]> = (0..200)
            .map(|k| [0.05 * k as f64, (0.1 * k as f64).sin()])
            .collect();
        let idx = MapIndex::new(pts, None).unwrap();
        let a = LikelihoodField::build(&idx, 0.05, 0.1, 4).unwrap();
        let b =
            LikelihoodField::from_distances(&idx, 0.05, 0.1, 4, a.distances().to_vec()).unwrap();
        assert_eq!((a.dist.clone(), a.pooled.clone()), (b.dist, b.pooled));
        let short = a.distances()[1..].to_vec();
        let e = LikelihoodField::from_distances(&idx, 0.05, 0.1, 4, short).unwrap_err();
        assert!(matches!(e, IcpError::InvalidInput { .. }), "{e}");
    }

    #[test]
    fn the_likelihood_byte_skips_only_exponentials_that_round_to_zero() {
        // every sigma the searches use, and distances swept finely through the cut-off
        // (where the byte goes 1 -> 0), far beyond it, and the odd values
        for sigma in [0.05, 0.1, 0.15, 0.2, 0.4, 1.0] {
            let inv2s2 = 1.0 / (2.0 * sigma * sigma);
            let cut = (ZERO_EXPONENT / inv2s2).sqrt() as f32;
            let mut ds: Vec<f32> = (0..20_000).map(|k| k as f32 * cut / 10_000.0).collect();
            ds.extend((0..2000).map(|k| cut * (1.0 + (k as f32 - 1000.0) * 1e-6)));
            ds.extend([0.0, -0.0, 1e-30, 1e30, f32::INFINITY, f32::NAN, f32::MAX]);
            for d in ds {
                assert_eq!(
                    likelihood_u8(d, inv2s2),
                    likelihood_u8_exact(d, inv2s2),
                    "sigma {sigma} d {d}"
                );
            }
            // the cut-off itself is in the zero tail
            assert_eq!(likelihood_u8_exact(cut * 0.999, inv2s2), 0, "sigma {sigma}");
        }
    }

    #[test]
    fn the_built_base_level_is_the_plain_formula_of_every_distance() {
        let pts: Vec<[f64; 2]> = (0..400)
            .map(|k| [0.05 * k as f64, 3.0 * (0.03 * k as f64).sin()])
            .collect();
        let idx = MapIndex::new(pts, None).unwrap();
        let sigma = 0.15;
        let f = LikelihoodField::build(&idx, 0.05, sigma, 3).unwrap();
        let inv2s2 = 1.0 / (2.0 * sigma * sigma);
        let want: Vec<u8> = f
            .dist
            .iter()
            .map(|&d| likelihood_u8_exact(d, inv2s2))
            .collect();
        assert!(want.contains(&0) && want.iter().any(|&b| b > 200));
        assert_eq!(f.pooled[0], want);
    }

    #[test]
    fn the_row_pooling_is_the_cell_by_cell_pooling() {
        // odd sizes, steps beyond the grid, a single row / column; bytes and booleans
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for (w, h) in [(1, 1), (1, 9), (9, 1), (7, 5), (33, 17), (130, 70)] {
            let bytes: Vec<u8> = (0..w * h).map(|_| next() as u8).collect();
            let flags: Vec<bool> = (0..w * h).map(|_| next() % 7 == 0).collect();
            for s in [1, 2, 4, 8, 16, 32, 64, 128, 256] {
                assert_eq!(
                    pool(&bytes, w, h, s, u8::max),
                    pool_plain(&bytes, w, h, s, u8::max),
                    "{w} x {h} step {s}"
                );
                assert_eq!(
                    pool(&flags, w, h, s, |a, b| a | b),
                    pool_plain(&flags, w, h, s, |a, b| a | b),
                    "{w} x {h} step {s}"
                );
            }
        }
    }

    #[test]
    fn a_grid_beyond_the_bound_is_grid_too_large() {
        let idx = MapIndex::new(vec![[0.0, 0.0], [5000.0, 5000.0]], None).unwrap();
        let e = LikelihoodField::build(&idx, 0.05, 0.1, 6).unwrap_err();
        assert!(
            matches!(e, IcpError::GridTooLarge { max: MAX_CELLS, .. }),
            "{e}"
        );
        assert!(e
            .to_string()
            .starts_with("resolution: a 5000.0 m x 5000.0 m map"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clearance_outside_the_grid_is_the_distance_to_it() {
        let pts = vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        let index = MapIndex::new(pts, None).unwrap();
        let f = LikelihoodField::build(&index, 0.1, 0.1, 2).unwrap();
        // inside: the stored distance
        let inside = [0.55, 0.55];
        assert_eq!(Some(f.clearance_at(inside)), f.distance_at(inside));
        // outside, beside the grid's right edge (x = 1.1: 11 cells of 0.1 m) and beyond a corner
        assert!((f.clearance_at([3.1, 0.5]) - 2.0).abs() < 1e-9);
        assert!((f.clearance_at([-3.0, -4.0]) - 5.0).abs() < 1e-9);
    }

    /// The stored distance of a point's cell, by `f64::floor` (the definition).
    fn floor_distance(f: &LikelihoodField, p: [f64; 2]) -> Option<f64> {
        let i = ((p[0] - f.x0) / f.res).floor();
        let j = ((p[1] - f.y0) / f.res).floor();
        if i >= 0.0 && j >= 0.0 && (i as usize) < f.w && (j as usize) < f.h {
            Some(f.dist[j as usize * f.w + i as usize] as f64)
        } else {
            None
        }
    }

    #[test]
    fn distances_are_read_from_the_floor_cell_everywhere() {
        let pts = vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.4, 0.7]];
        let index = MapIndex::new(pts, None).unwrap();
        let f = LikelihoodField::build(&index, 0.1, 0.1, 2).unwrap();
        let mut rng = crate::testkit::Rng::new(4);
        let (x1, y1) = (f.x0 + f.w as f64 * f.res, f.y0 + f.h as f64 * f.res);
        let mut ps: Vec<[f64; 2]> = (0..20_000)
            .map(|_| {
                [
                    rng.range(f.x0 - 1.0, x1 + 1.0),
                    rng.range(f.y0 - 1.0, y1 + 1.0),
                ]
            })
            .collect();
        // cell borders, the grid's edges, -0, NaN and infinities
        for k in 0..=f.w + 1 {
            ps.push([f.x0 + k as f64 * f.res, f.y0 + 0.35]);
        }
        ps.extend([
            [f.x0, f.y0],
            [x1, y1],
            [f.x0 - 1e-12, f.y0],
            [-0.0, -0.0],
            [f64::NAN, 0.5],
            [0.5, f64::NAN],
            [f64::INFINITY, 0.5],
            [f64::NEG_INFINITY, 0.5],
            [0.5, 1e300],
        ]);
        let mut inside = 0;
        for p in ps {
            let want = floor_distance(&f, p);
            assert_eq!(f.distance_at(p), want, "point {p:?}");
            inside += usize::from(want.is_some());
        }
        assert!(inside > 2000, "{inside}");
    }
}
