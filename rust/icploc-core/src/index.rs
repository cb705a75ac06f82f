//! The map index: an immutable k-d tree (kiddo) over the map's 2D points, with unit normals.

use std::num::NonZeroUsize;
use std::sync::OnceLock;

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

mod closest_grid;
mod hugepages;
pub mod objects;
pub mod runs;

use closest_grid::ClosestGrid;
pub use closest_grid::FILL_VERSION as GRID_FILL_VERSION;

use crate::error::{IcpError, Result};
use crate::se2::{wrap_angle, Pose2};

type Tree = ImmutableKdTree<f64, u32, 2, 32>;

/// The tree is built in a frame turned by this angle (rad): maps are full of axis-aligned
/// walls whose points share one coordinate exactly, which degrades a k-d tree badly
/// (measured: 15 µs instead of 0.4 µs per query at 1M wall points). Distances do not
/// change under a rotation, so queries are turned the same way and answers are exact.
#[cfg(test)]
const TREE_ANGLE: f64 = 0.618_033_988_749_894_9;
const TREE_COS: f64 = 0.815_019_204_687_878_8; // cos(TREE_ANGLE)
const TREE_SIN: f64 = 0.579_433_944_457_810_9; // sin(TREE_ANGLE)

#[inline(always)]
fn to_tree(p: [f64; 2]) -> [f64; 2] {
    [
        TREE_COS * p[0] - TREE_SIN * p[1],
        TREE_SIN * p[0] + TREE_COS * p[1],
    ]
}

/// Neighbours used to estimate a normal when none are given.
const NORMAL_NEIGHBOURS: usize = 7;

/// Default cell size of the closest-point grid (m).
pub const DEFAULT_CACHE_RESOLUTION: f64 = 0.02;
/// The closest-point grid never holds more cells than this (4 bytes each: 32 MB); when the
/// requested resolution needs more, there is no grid and ICP gets exact k-d tree answers.
pub const MAX_CACHE_CELLS: usize = 1 << 23;
/// Answers through the grid are within its tolerance of the exact ones whenever the nearest
/// map point is within this distance (m) of the query: grid tiles exist within this distance
/// (plus two cells) of every map point, and only there.
pub const CACHE_REACH: f64 = 2.0;
/// The least link distance (m) of the map's pieces ([`MapIndex::objects`]).
pub const OBJECT_LINK: f64 = 0.05;

/// Map coordinates must lie within ±this (m): beyond it squared distances and centimetre
/// cells stop being representable.
pub const MAX_MAP_COORDINATE: f64 = 1e9;

/// An immutable nearest-neighbour index over 2D map points, with optional unit normals.
///
/// Queries go to a kiddo k-d tree. ICP's correspondence search may go through an optional
/// closest-point grid (see [`MapIndex::with_cache`]) that answers with the closest map
/// point of the query's cell centre: at most `1.67·resolution` farther than the exact
/// nearest point, and O(1) whatever the map's size or density.
pub struct MapIndex {
    tree: Tree,
    cache: Option<ClosestGrid>,
    /// why the requested grid was not built (ICP then gets exact tree answers)
    cache_fallback: Option<String>,
    points: Vec<[f64; 2]>,
    normals: OnceLock<Vec<[f64; 2]>>,
    normals_given: bool,
    spacing: OnceLock<f64>,
    bounds: [f64; 4],
    /// The likelihood pyramid of `icp()`'s window search, built on first use (`None`: the
    /// map is too large for it).
    likelihood: OnceLock<Option<crate::likelihood::LikelihoodField>>,
    /// hook (core4): the histogram of the map's line directions (`icp()`'s heading prior),
    /// built on first use.
    directions: OnceLock<Vec<f32>>,
    /// the map's connected pieces (see-through of small objects that left), built on
    /// first use.
    objects: OnceLock<objects::Objects>,
}

impl std::fmt::Debug for MapIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MapIndex")
            .field("len", &self.points.len())
            .field("normals_given", &self.normals_given)
            .field("bounds", &self.bounds)
            .finish()
    }
}

impl MapIndex {
    /// Build the index. Points must be finite; normals, when given, must match the points
    /// in number, be finite and non-zero (they are normalised to unit length).
    pub fn new(points: Vec<[f64; 2]>, normals: Option<Vec<[f64; 2]>>) -> Result<Self> {
        if points.is_empty() {
            return Err(IcpError::EmptyMap);
        }
        if points.len() >= u32::MAX as usize {
            return Err(IcpError::InvalidInput {
                what: "map points".into(),
                reason: format!("{} points is more than the index supports", points.len()),
            });
        }
        crate::check_finite("map points", &points)?;
        if let Some(row) = points
            .iter()
            .position(|p| !(p[0].abs() <= MAX_MAP_COORDINATE && p[1].abs() <= MAX_MAP_COORDINATE))
        {
            let p = points[row];
            return Err(IcpError::InvalidInput {
                what: "map points".into(),
                reason: format!(
                    "row {row} ({:e}, {:e}) is farther than {MAX_MAP_COORDINATE:e} m from the \
                     origin (map coordinates are metres)",
                    p[0], p[1]
                ),
            });
        }
        let normals_given = normals.is_some();
        let normals_lock = OnceLock::new();
        if let Some(mut n) = normals {
            if n.len() != points.len() {
                return Err(IcpError::Shape {
                    what: "map normals".into(),
                    expected: format!("{} rows (one per map point)", points.len()),
                    got: format!("{} rows", n.len()),
                });
            }
            crate::check_finite("map normals", &n)?;
            for (row, v) in n.iter_mut().enumerate() {
                let len = (v[0] * v[0] + v[1] * v[1]).sqrt();
                if !(len > 1e-9) {
                    return Err(IcpError::InvalidInput {
                        what: "map normals".into(),
                        reason: format!("zero-length normal at row {row}"),
                    });
                }
                v[0] /= len;
                v[1] /= len;
            }
            let _ = normals_lock.set(n);
        }
        let mut bounds = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for p in &points {
            bounds[0] = bounds[0].min(p[0]);
            bounds[1] = bounds[1].min(p[1]);
            bounds[2] = bounds[2].max(p[0]);
            bounds[3] = bounds[3].max(p[1]);
        }
        let turned: Vec<[f64; 2]> = points.iter().map(|p| to_tree(*p)).collect();
        let tree = Tree::new_from_slice(&turned);
        drop(turned);
        Ok(Self {
            tree,
            cache: None,
            cache_fallback: None,
            points,
            normals: normals_lock,
            normals_given,
            spacing: OnceLock::new(),
            bounds,
            likelihood: OnceLock::new(),
            directions: OnceLock::new(),
            objects: OnceLock::new(),
        })
    }

    /// Add a closest-point grid of cell size `resolution` (m) for ICP correspondences;
    /// `None` or 0 removes it (exact k-d tree answers only).
    ///
    /// The grid is sized from where the map is: tiles of 32 × 32 cells exist within
    /// [`CACHE_REACH`] of map points and across gaps of up to 16 tiles between them (the
    /// whole tile box when that at most doubles the cells), so a stray point far from the
    /// building costs a few tiles, not resolution. The resolution
    /// is never coarsened: when the grid would need more than [`MAX_CACHE_CELLS`] cells
    /// (or the map spans more than it can address) there is no grid, ICP gets exact tree
    /// answers, and [`MapIndex::cache_fallback`] says why.
    pub fn with_cache(mut self, resolution: Option<f64>) -> Result<Self> {
        self.cache = None;
        self.cache_fallback = None;
        match resolution.filter(|r| *r != 0.0) {
            None => {}
            Some(r) if !(r > 0.0 && r.is_finite()) => {
                return Err(IcpError::InvalidConfig {
                    field: "cache_resolution",
                    value: r.to_string(),
                    reason: "must be positive and finite (or 0/None for no cache)",
                })
            }
            Some(r) => {
                match ClosestGrid::build(&self.points, self.bounds, r, CACHE_REACH, MAX_CACHE_CELLS)
                {
                    Ok(g) => self.cache = Some(g),
                    Err(why) => {
                        self.cache_fallback = Some(format!(
                            "closest-point grid at cache_resolution={r} m not built: {why}; \
                             ICP uses exact (slower) k-d tree answers"
                        ))
                    }
                }
            }
        }
        Ok(self)
    }

    /// The closest-point grid's cells in storage order (map point indices, `u32::MAX` for
    /// none), to save them and rebuild the same index with [`MapIndex::with_cache_cells`]
    /// without computing them again; `None` without a grid.
    pub fn cache_cells(&self) -> Option<std::borrow::Cow<'_, [u32]>> {
        self.cache.as_ref().map(|c| c.cells())
    }

    /// [`MapIndex::with_cache`]`(Some(resolution))` with the grid's cells taken from an
    /// earlier build of the same points at the same resolution ([`MapIndex::cache_cells`])
    /// instead of computed: the same index, without the grid's fill (most of its build
    /// time). The layout is computed from the points; cells that do not fit it (another
    /// length, an index naming no point) are an error, never a silently wrong grid. Cells
    /// of other points that happen to fit cannot be told apart: the caller keys them by
    /// the points.
    pub fn with_cache_cells(self, resolution: f64, cells: Vec<u32>) -> Result<Self> {
        check_cache_resolution(resolution)?;
        self.install_given(|points, bounds| {
            ClosestGrid::with_cells(
                points,
                bounds,
                resolution,
                CACHE_REACH,
                MAX_CACHE_CELLS,
                cells,
            )
        })
    }

    /// [`MapIndex::with_cache_cells`] with the cells given as [`runs::encode`]'s runs
    /// (`values`, `lengths`) and decoded block by block when queries first reach them, not
    /// all at once: a saved grid of a building is tens of MB of cells, of which a replay
    /// reads a part, so loading the index costs little more than reading the runs. Runs that
    /// do not decode are an error naming the "grid runs"; cells that do not fit the layout
    /// are one as in `with_cache_cells`.
    pub fn with_cache_runs(
        self,
        resolution: f64,
        values: Vec<u32>,
        lengths: &[u32],
    ) -> Result<Self> {
        check_cache_resolution(resolution)?;
        runs::total(&values, lengths, MAX_CACHE_CELLS).map_err(|reason| {
            IcpError::InvalidInput {
                what: "grid runs".into(),
                reason,
            }
        })?;
        self.install_given(|points, bounds| {
            ClosestGrid::with_runs(
                points,
                bounds,
                resolution,
                CACHE_REACH,
                MAX_CACHE_CELLS,
                values,
                lengths,
            )
        })
    }

    /// The grid `build` makes from the points and bounds, given cells rather than computed
    /// ones ([`MapIndex::with_cache_cells`], [`MapIndex::with_cache_runs`]), as the index's
    /// closest-point grid; cells that do not fit are an error naming them.
    fn install_given(
        mut self,
        build: impl FnOnce(
            &[[f64; 2]],
            [f64; 4],
        ) -> std::result::Result<
            std::result::Result<ClosestGrid, String>,
            closest_grid::Unbuilt,
        >,
    ) -> Result<Self> {
        self.cache = None;
        self.cache_fallback = None;
        let bad = |reason: String| IcpError::InvalidInput {
            what: "closest-point grid cells".into(),
            reason,
        };
        match build(&self.points, self.bounds) {
            Ok(Ok(g)) => self.cache = Some(g),
            Ok(Err(why)) => return Err(bad(why)),
            Err(why) => return Err(bad(format!("no grid at this resolution: {why}"))),
        }
        Ok(self)
    }

    /// Cell size of the closest-point grid, if there is one (it is always the requested one).
    pub fn cache_resolution(&self) -> Option<f64> {
        self.cache.as_ref().map(|c| c.resolution())
    }

    /// How much farther than the exact nearest point an answer of [`MapIndex::correspondence`]
    /// may be (m): `(√2 + 0.25)·resolution` with a grid, 0 without one.
    pub fn cache_tolerance(&self) -> f64 {
        self.cache_resolution().map_or(0.0, |r| {
            (std::f64::consts::SQRT_2 + closest_grid::CELL_ERROR) * r
        })
    }

    /// Why the requested closest-point grid was not built, if it was not (ICP then gets
    /// exact k-d tree answers, which are slower).
    pub fn cache_fallback(&self) -> Option<&str> {
        self.cache_fallback.as_deref()
    }

    /// Heap bytes held by the closest-point grid (0 without one).
    pub fn cache_bytes(&self) -> usize {
        self.cache.as_ref().map_or(0, |c| c.bytes())
    }

    /// Number of tiles of the closest-point grid (0 without one).
    pub fn cache_tiles(&self) -> usize {
        self.cache.as_ref().map_or(0, |c| c.tiles())
    }

    /// The correspondence query of ICP. Returns (squared distance from `q` to the returned
    /// point, its index). When the exact nearest map point is within [`CACHE_REACH`] of `q`,
    /// the answer is at most [`MapIndex::cache_tolerance`] farther (`(√2 + 0.25)·resolution`:
    /// √2 from answering for the cell's centre, 0.25 from the grid's propagation); when none
    /// is, it is a map point farther than `CACHE_REACH` (so a correspondence threshold up to
    /// 2 m rejects it, as it would the exact one): the grid cell's (usually the nearest) or,
    /// outside the grid's tiles, the exact k-d tree answer. Without a grid: exact.
    #[inline]
    pub fn correspondence(&self, q: [f64; 2]) -> (f64, usize) {
        if let Some(c) = &self.cache {
            if let Some(j) = c.lookup(q) {
                let p = self.points[j];
                let d2 = (p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]);
                return (d2, j);
            }
        }
        self.nearest(q)
    }

    /// [`MapIndex::correspondence`] of each of `qs` into `out` (squared distance, index),
    /// the same answers: the grid cells of all the queries are read first, then their
    /// points (the reads of one pass do not wait on each other, so their cache misses
    /// overlap; in one pass each query's point waits for its cell).
    #[inline]
    pub fn correspondences(&self, qs: &[[f64; 2]], out: &mut [(f64, u32)]) {
        assert_eq!(qs.len(), out.len(), "one answer per query");
        let Some(c) = &self.cache else {
            for (q, o) in qs.iter().zip(out.iter_mut()) {
                let (d2, j) = self.nearest(*q);
                *o = (d2, j as u32);
            }
            return;
        };
        c.lookup_into(qs, out);
        for (q, o) in qs.iter().zip(out.iter_mut()) {
            *o = if o.1 != u32::MAX {
                let p = self.points[o.1 as usize];
                let d2 = (p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]);
                (d2, o.1)
            } else {
                let (d2, j) = self.nearest(*q);
                (d2, j as u32)
            };
        }
    }

    /// [`MapIndex::correspondences`] for a caller that rejects every answer farther than
    /// [`CACHE_REACH`] (ICP's threshold passes): a query outside the grid's tiles — no map
    /// point within `CACHE_REACH`, whose exact answer the k-d tree would give — gets
    /// `(f64::INFINITY, u32::MAX)` instead; every other answer is the same. Without a
    /// grid: the same as `correspondences`.
    #[inline]
    pub(crate) fn correspondences_within_reach(&self, qs: &[[f64; 2]], out: &mut [(f64, u32)]) {
        assert_eq!(qs.len(), out.len(), "one answer per query");
        let Some(c) = &self.cache else {
            return self.correspondences(qs, out);
        };
        c.lookup_into(qs, out);
        for (q, o) in qs.iter().zip(out.iter_mut()) {
            o.0 = if o.1 != u32::MAX {
                let p = self.points[o.1 as usize];
                (p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1])
            } else {
                f64::INFINITY
            };
        }
    }

    #[inline]
    pub fn len(&self) -> usize {
        self.points.len()
    }

    #[inline]
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    #[inline]
    pub fn points(&self) -> &[[f64; 2]] {
        &self.points
    }

    /// (xmin, ymin, xmax, ymax).
    pub fn bounds(&self) -> [f64; 4] {
        self.bounds
    }

    /// True when the normals were given at construction (not estimated).
    pub fn has_normals(&self) -> bool {
        self.normals_given
    }

    /// Unit normals: the given ones, or estimated once (PCA of the nearest neighbours).
    pub fn normals(&self) -> &[[f64; 2]] {
        self.normals.get_or_init(|| self.estimate_normals())
    }

    /// hook (core4): the histogram of the map's line directions ([`crate::icp`]'s heading
    /// prior), built on first use and kept.
    pub fn line_directions(&self) -> &[f32] {
        self.directions
            .get_or_init(|| crate::icp::map_directions(self.normals()))
    }

    /// The map's connected pieces ([`objects::Objects`]: points linked within
    /// max(5 cm, 1.5 sample spacings)), built on first use and kept.
    pub fn objects(&self) -> &objects::Objects {
        self.objects.get_or_init(|| {
            objects::Objects::build(&self.points, (1.5 * self.spacing()).max(OBJECT_LINK))
        })
    }

    /// Whether [`MapIndex::objects`] has been built.
    #[cfg(test)]
    pub(crate) fn objects_built(&self) -> bool {
        self.objects.get().is_some()
    }

    /// The max-pooled likelihood pyramid of the window search of `icp()`
    /// ([`crate::likelihood`]), built on first use and kept; `None` when the map's bounds
    /// need more than 2²³ cells even at 20 cm.
    pub fn likelihood_field(&self) -> Option<&crate::likelihood::LikelihoodField> {
        self.likelihood
            .get_or_init(|| crate::likelihood::LikelihoodField::for_window(self))
            .as_ref()
    }

    /// Closest map point: (squared distance, index).
    #[inline]
    pub fn nearest(&self, q: [f64; 2]) -> (f64, usize) {
        let nn = self.tree.nearest_one::<SquaredEuclidean>(&to_tree(q));
        let j = nn.item as usize;
        let p = self.points[j];
        (
            (p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]),
            j,
        )
    }

    /// Indices of the points within `radius` of `center`, sorted ascending.
    pub fn within(&self, center: [f64; 2], radius: f64) -> Vec<usize> {
        if !(radius >= 0.0) || !center[0].is_finite() || !center[1].is_finite() {
            return Vec::new();
        }
        let mut v: Vec<usize> = self
            .tree
            .within_unsorted::<SquaredEuclidean>(&to_tree(center), radius * radius)
            .into_iter()
            .map(|nn| nn.item as usize)
            .collect();
        v.sort_unstable();
        v
    }

    /// Median distance between a map point and its nearest neighbour (estimated on a
    /// sample of at most 2,000 points; 0 for a single-point map).
    pub fn spacing(&self) -> f64 {
        *self.spacing.get_or_init(|| {
            let n = self.points.len();
            if n < 2 {
                return 0.0;
            }
            let step = (n / 2000).max(1);
            let k = NonZeroUsize::new(2).expect("2 is non-zero");
            let mut d: Vec<f64> = (0..n)
                .step_by(step)
                .map(|i| {
                    let nn = self
                        .tree
                        .nearest_n::<SquaredEuclidean>(&to_tree(self.points[i]), k);
                    nn.last().map(|x| x.distance.sqrt()).unwrap_or(0.0)
                })
                .collect();
            let mid = d.len() / 2;
            d.select_nth_unstable_by(mid, f64::total_cmp);
            d[mid]
        })
    }

    fn estimate_normals(&self) -> Vec<[f64; 2]> {
        let k = NonZeroUsize::new(NORMAL_NEIGHBOURS.min(self.points.len()).max(1))
            .expect("at least one neighbour");
        self.points
            .par_iter()
            .map(|p| {
                let nn = self.tree.nearest_n::<SquaredEuclidean>(&to_tree(*p), k);
                let m = nn.len() as f64;
                let (mut mx, mut my) = (0.0, 0.0);
                for x in &nn {
                    let q = self.points[x.item as usize];
                    mx += q[0];
                    my += q[1];
                }
                mx /= m;
                my /= m;
                let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
                for x in &nn {
                    let q = self.points[x.item as usize];
                    let (dx, dy) = (q[0] - mx, q[1] - my);
                    sxx += dx * dx;
                    sxy += dx * dy;
                    syy += dy * dy;
                }
                smallest_eigenvector(sxx, sxy, syy)
            })
            .collect()
    }

    /// Indices of the map points a scanner at `pose` could see: within `max_range`, inside
    /// the field of view `fov` (radians, centred on the heading), and not hidden behind a
    /// nearer point. Each point occludes the arc of half-width `point_radius` it subtends;
    /// a point is visible when it is at most `tolerance` farther than the nearest occluder
    /// on its own bearing. Returns sorted indices.
    pub fn visible(
        &self,
        pose: Pose2,
        fov: f64,
        max_range: f64,
        point_radius: Option<f64>,
        tolerance: f64,
        angular_resolution: f64,
    ) -> Result<Vec<usize>> {
        if !pose.is_finite() {
            return Err(IcpError::InvalidInput {
                what: "pose".into(),
                reason: "must be finite".into(),
            });
        }
        for (field, v) in [
            ("fov", fov),
            ("max_range", max_range),
            ("angular_resolution", angular_resolution),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(IcpError::InvalidConfig {
                    field,
                    value: v.to_string(),
                    reason: "must be positive and finite",
                });
            }
        }
        if !(tolerance >= 0.0 && tolerance.is_finite()) {
            return Err(IcpError::InvalidConfig {
                field: "tolerance",
                value: tolerance.to_string(),
                reason: "must be non-negative and finite",
            });
        }
        let radius = match point_radius {
            Some(r) if r >= 0.0 && r.is_finite() => r,
            Some(r) => {
                return Err(IcpError::InvalidConfig {
                    field: "point_radius",
                    value: r.to_string(),
                    reason: "must be non-negative and finite",
                })
            }
            None => 0.5 * self.spacing(),
        };
        let fov = fov.min(std::f64::consts::TAU);
        let half = 0.5 * fov;
        let nbins = ((fov / angular_resolution).ceil() as usize).clamp(1, 10_000_000);
        let res = fov / nbins as f64;
        let mut zbuf = vec![f64::INFINITY; nbins];
        let cand = self
            .tree
            .within_unsorted::<SquaredEuclidean>(&to_tree([pose.x, pose.y]), max_range * max_range);
        // (index, range, bin of the bearing)
        let mut keep: Vec<(usize, f64, usize)> = Vec::with_capacity(cand.len());
        let full_circle = fov >= std::f64::consts::TAU - 1e-12;
        for nn in cand {
            let i = nn.item as usize;
            let p = self.points[i];
            let (dx, dy) = (p[0] - pose.x, p[1] - pose.y);
            let r = nn.distance.sqrt();
            if r < 1e-9 {
                continue;
            }
            let bearing = wrap_angle(dy.atan2(dx) - pose.theta);
            let h = if r > radius {
                (radius / r).asin()
            } else {
                half
            };
            let rel = bearing + half; // in [0, fov] when inside the view
            if !full_circle && (rel + h < 0.0 || rel - h > fov) {
                continue;
            }
            let lo = ((rel - h) / res).floor() as i64;
            let hi = ((rel + h) / res).floor() as i64;
            for b in lo..=hi {
                let bin = if full_circle {
                    b.rem_euclid(nbins as i64) as usize
                } else if b < 0 || b >= nbins as i64 {
                    continue;
                } else {
                    b as usize
                };
                if r < zbuf[bin] {
                    zbuf[bin] = r;
                }
            }
            if full_circle || (0.0..=fov).contains(&rel) {
                let c = ((rel / res).floor() as i64).rem_euclid(nbins as i64) as usize;
                keep.push((i, r, c.min(nbins - 1)));
            }
        }
        let mut out: Vec<usize> = keep
            .into_iter()
            .filter(|&(_, r, c)| r <= zbuf[c] + tolerance)
            .map(|(i, _, _)| i)
            .collect();
        out.sort_unstable();
        Ok(out)
    }
}

/// Unit eigenvector of the smaller eigenvalue of [[a, b], [b, c]].
fn smallest_eigenvector(a: f64, b: f64, c: f64) -> [f64; 2] {
    // Principal direction angle of the scatter: tan(2φ) = 2b / (a − c); the normal is
    // perpendicular to it.
    if a == 0.0 && b == 0.0 && c == 0.0 {
        return [1.0, 0.0];
    }
    let phi = 0.5 * (2.0 * b).atan2(a - c);
    let (s, co) = phi.sin_cos();
    [-s, co]
}

/// A closest-point grid's cell size must be positive and finite.
fn check_cache_resolution(resolution: f64) -> Result<()> {
    if resolution > 0.0 && resolution.is_finite() {
        Ok(())
    } else {
        Err(IcpError::InvalidConfig {
            field: "cache_resolution",
            value: resolution.to_string(),
            reason: "must be positive and finite",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall_points() -> Vec<[f64; 2]> {
        // Axis-aligned walls: many identical coordinates on one axis.
        let mut v = Vec::new();
        for i in 0..=100 {
            let t = i as f64 * 0.05;
            v.push([t, 0.0]);
            v.push([t, 5.0]);
            v.push([0.0, t]);
            v.push([5.0, t]);
        }
        v
    }

    /// Walls and scattered points, and their index with a 2 cm closest-point grid.
    fn built_walls(rng: &mut crate::testkit::Rng) -> (Vec<[f64; 2]>, MapIndex) {
        let mut pts = wall_points();
        pts.extend((0..200).map(|_| [rng.range(-1.0, 6.0), rng.range(-1.0, 6.0)]));
        let built = MapIndex::new(pts.clone(), None)
            .unwrap()
            .with_cache(Some(0.02))
            .unwrap();
        (pts, built)
    }

    /// The batch look-up answers each query as the single one does, with a grid (queries
    /// inside it, beyond its tiles, NaN) and without one (exact answers).
    #[test]
    fn batched_correspondences_are_the_single_answers() {
        let mut rng = crate::testkit::Rng::new(31);
        let (pts, built) = built_walls(&mut rng);
        let plain = MapIndex::new(pts, None).unwrap();
        let mut qs: Vec<[f64; 2]> = (0..2000)
            .map(|_| [rng.range(-1.5, 6.5), rng.range(-1.5, 6.5)])
            .collect();
        qs.extend((0..200).map(|_| [rng.range(-40.0, 40.0), rng.range(-40.0, 40.0)]));
        qs.push([f64::NAN, 1.0]);
        for idx in [&built, &plain] {
            let mut out = vec![(0.0, 0u32); qs.len()];
            idx.correspondences(&qs, &mut out);
            for (q, &(d2, j)) in qs.iter().zip(&out) {
                let (e2, k) = idx.correspondence(*q);
                assert_eq!(j as usize, k, "query {q:?}");
                assert!(d2 == e2 || (d2.is_nan() && e2.is_nan()), "query {q:?}");
            }
        }
    }

    /// The batch look-up for ICP's threshold passes: every answer within the grid's reach
    /// is the plain batch's; a query it leaves unanswered has no map point within the reach
    /// (exact distance beyond `CACHE_REACH`). Without a grid: the plain batch's answers.
    #[test]
    fn look_ups_within_reach_answer_every_query_within_it() {
        let mut rng = crate::testkit::Rng::new(37);
        let (pts, built) = built_walls(&mut rng);
        let plain = MapIndex::new(pts, None).unwrap();
        let mut qs: Vec<[f64; 2]> = (0..2000)
            .map(|_| [rng.range(-3.0, 8.0), rng.range(-3.0, 8.0)])
            .collect();
        qs.extend((0..300).map(|_| [rng.range(-40.0, 40.0), rng.range(-40.0, 40.0)]));
        let (mut unanswered, mut far) = (0usize, 0usize);
        for idx in [&built, &plain] {
            let mut all = vec![(0.0, 0u32); qs.len()];
            let mut near = vec![(0.0, 0u32); qs.len()];
            idx.correspondences(&qs, &mut all);
            idx.correspondences_within_reach(&qs, &mut near);
            for (q, (a, b)) in qs.iter().zip(all.iter().zip(&near)) {
                let exact = idx.nearest(*q).0;
                far += (exact > CACHE_REACH * CACHE_REACH) as usize;
                if b.1 == u32::MAX {
                    unanswered += 1;
                    assert!(idx.cache.is_some(), "query {q:?} unanswered without a grid");
                    assert_eq!(b.0, f64::INFINITY, "query {q:?}");
                    assert!(exact > CACHE_REACH * CACHE_REACH, "query {q:?}: {exact}");
                } else {
                    assert_eq!(a, b, "query {q:?}");
                }
            }
        }
        // the far queries exist, and the grid leaves most of them to no one
        assert!(far > 400, "{far} far queries");
        assert!(unanswered > 200, "{unanswered} unanswered");
    }

    #[test]
    fn saved_grid_cells_rebuild_the_same_index() {
        let mut rng = crate::testkit::Rng::new(21);
        let (pts, built) = built_walls(&mut rng);
        let (v, n) = runs::encode(&built.cache_cells().unwrap());
        let cells = runs::decode(&v, &n, MAX_CACHE_CELLS).unwrap();
        assert!(
            v.len() * 10 < cells.len(),
            "{} runs of {} cells",
            v.len(),
            cells.len()
        );
        let loaded = MapIndex::new(pts.clone(), None)
            .unwrap()
            .with_cache_cells(0.02, cells.clone())
            .unwrap();
        assert_eq!(loaded.cache_cells(), built.cache_cells());
        for _ in 0..2000 {
            let q = [rng.range(-3.0, 8.0), rng.range(-3.0, 8.0)];
            assert_eq!(loaded.correspondence(q), built.correspondence(q));
        }
    }

    #[test]
    fn saved_grid_runs_rebuild_the_same_index_lazily() {
        let mut rng = crate::testkit::Rng::new(22);
        let (pts, built) = built_walls(&mut rng);
        let (v, n) = runs::encode(&built.cache_cells().unwrap());
        let loaded = MapIndex::new(pts.clone(), None)
            .unwrap()
            .with_cache_runs(0.02, v.clone(), &n)
            .unwrap();
        for _ in 0..2000 {
            let q = [rng.range(-3.0, 8.0), rng.range(-3.0, 8.0)];
            assert_eq!(loaded.correspondence(q), built.correspondence(q));
        }
        assert_eq!(loaded.cache_cells(), built.cache_cells());
        let fresh = || MapIndex::new(pts.clone(), None).unwrap();
        let k = v.len() - 1;
        let short = fresh()
            .with_cache_runs(0.02, v[..k].to_vec(), &n[..k])
            .unwrap_err();
        assert!(short.to_string().contains("cells given"), "{short}");
        let unpaired = fresh()
            .with_cache_runs(0.02, v.clone(), &n[..k])
            .unwrap_err();
        assert!(unpaired.to_string().contains("grid runs"), "{unpaired}");
        let mut wrong = v.clone();
        wrong[0] = pts.len() as u32;
        let e = fresh().with_cache_runs(0.02, wrong, &n).unwrap_err();
        assert!(e.to_string().contains("cell 0 names point"), "{e}");
    }

    #[test]
    fn saved_grid_cells_that_do_not_fit_are_refused() {
        let pts = wall_points();
        let built = MapIndex::new(pts.clone(), None)
            .unwrap()
            .with_cache(Some(0.02))
            .unwrap();
        let cells = built.cache_cells().unwrap().to_vec();
        let fresh = || MapIndex::new(pts.clone(), None).unwrap();
        let short = fresh()
            .with_cache_cells(0.02, cells[1..].to_vec())
            .unwrap_err();
        assert!(short.to_string().contains("cells given"), "{short}");
        let mut wrong = cells.clone();
        wrong[5] = pts.len() as u32;
        let e = fresh().with_cache_cells(0.02, wrong).unwrap_err();
        assert!(e.to_string().contains("names point"), "{e}");
        let other_res = fresh().with_cache_cells(0.05, cells).unwrap_err();
        assert!(other_res.to_string().contains("cells given"), "{other_res}");
    }

    #[test]
    fn tree_rotation_constants_agree() {
        assert!((TREE_ANGLE.cos() - TREE_COS).abs() < 1e-15);
        assert!((TREE_ANGLE.sin() - TREE_SIN).abs() < 1e-15);
    }

    #[test]
    fn empty_map_is_an_error() {
        assert_eq!(MapIndex::new(vec![], None).unwrap_err(), IcpError::EmptyMap);
    }

    #[test]
    fn nan_is_an_error() {
        let e = MapIndex::new(vec![[0.0, 0.0], [f64::NAN, 1.0]], None).unwrap_err();
        assert!(matches!(e, IcpError::NonFinite { row: 1, .. }));
    }

    #[test]
    fn normals_shape_and_zero() {
        let e = MapIndex::new(vec![[0.0, 0.0]], Some(vec![])).unwrap_err();
        assert!(matches!(e, IcpError::Shape { .. }));
        let e = MapIndex::new(vec![[0.0, 0.0]], Some(vec![[0.0, 0.0]])).unwrap_err();
        assert!(matches!(e, IcpError::InvalidInput { .. }));
    }

    #[test]
    fn nearest_matches_brute_force_with_duplicates_on_axes() {
        let pts = wall_points();
        let idx = MapIndex::new(pts.clone(), None).unwrap();
        for q in [[0.3, 0.2], [2.5, 2.4], [4.9, 4.0], [-1.0, 7.0], [2.51, 0.0]] {
            let (d2, i) = idx.nearest(q);
            let best = pts
                .iter()
                .map(|p| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2))
                .fold(f64::INFINITY, f64::min);
            assert!((d2 - best).abs() < 1e-12);
            let p = pts[i];
            assert!(((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) - best).abs() < 1e-12);
        }
    }

    fn brute_d2(pts: &[[f64; 2]], q: [f64; 2]) -> f64 {
        pts.iter()
            .map(|p| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2))
            .fold(f64::INFINITY, f64::min)
    }

    /// The documented tolerance of an answer through the grid: `(√2 + CELL_ERROR)·res`
    /// farther than the exact nearest point (plus rounding relative to the coordinates' size).
    fn within_tolerance(
        idx: &MapIndex,
        pts: &[[f64; 2]],
        q: [f64; 2],
    ) -> std::result::Result<(), String> {
        let (d2, j) = idx.correspondence(q);
        let p = pts[j];
        let own = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
        if own != d2 {
            return Err(format!(
                "{q:?}: reported d2 {d2} is not that of point {j} ({own})"
            ));
        }
        let exact = brute_d2(pts, q).sqrt();
        let res = idx.cache_resolution().unwrap_or(0.0);
        let scale = q[0].abs().max(q[1].abs()).max(1.0);
        if d2.sqrt()
            <= exact + res * (std::f64::consts::SQRT_2 + closest_grid::CELL_ERROR) + 1e-12 * scale
        {
            Ok(())
        } else {
            Err(format!(
                "{q:?}: answer at {} m, nearest at {exact} m",
                d2.sqrt()
            ))
        }
    }

    #[test]
    fn cache_answers_within_a_cell_of_exact() {
        let pts = wall_points();
        let cached = MapIndex::new(pts.clone(), None)
            .unwrap()
            .with_cache(Some(0.02))
            .unwrap();
        assert_eq!(cached.cache_resolution(), Some(0.02));
        assert_eq!(cached.cache_fallback(), None);
        assert!((cached.cache_tolerance() - 0.02 * 1.664_213_562_373_095).abs() < 1e-15);
        let mut rng = crate::testkit::Rng::new(4);
        for _ in 0..5000 {
            let q = [rng.range(-3.0, 8.0), rng.range(-3.0, 8.0)];
            within_tolerance(&cached, &pts, q).unwrap();
        }
    }

    #[test]
    fn cache_resolution_must_be_positive_and_zero_means_none() {
        assert!(MapIndex::new(vec![[0.0, 0.0]], None)
            .unwrap()
            .with_cache(Some(-1.0))
            .is_err());
        let idx = MapIndex::new(vec![[0.0, 0.0]], None)
            .unwrap()
            .with_cache(Some(0.0))
            .unwrap();
        assert_eq!(idx.cache_resolution(), None);
        assert_eq!(idx.cache_fallback(), None);
        assert_eq!(idx.cache_bytes(), 0);
    }

    /// The building of wall_points() with one 10 m segment 5 km away.
    fn with_stray_segment() -> Vec<[f64; 2]> {
        let mut pts = wall_points();
        for i in 0..=200 {
            pts.push([-5000.0 + i as f64 * 0.05, -3000.0]);
        }
        pts
    }

    #[test]
    fn a_stray_far_segment_keeps_the_resolution() {
        let plain = MapIndex::new(wall_points(), None)
            .unwrap()
            .with_cache(Some(0.02))
            .unwrap();
        let pts = with_stray_segment();
        let idx = MapIndex::new(pts.clone(), None)
            .unwrap()
            .with_cache(Some(0.02))
            .unwrap();
        assert_eq!(idx.cache_resolution(), Some(0.02));
        assert_eq!(idx.cache_fallback(), None);
        // the segment costs the tiles around itself only: (16 + 8) × 9 tiles of 0.64 m, 4 KB each
        assert!(
            idx.cache_bytes() < plain.cache_bytes() + 216 * 4096 + (1 << 16),
            "{} vs {}",
            idx.cache_bytes(),
            plain.cache_bytes()
        );
        let mut rng = crate::testkit::Rng::new(9);
        for _ in 0..3000 {
            let q = [rng.range(-1.0, 6.0), rng.range(-1.0, 6.0)];
            within_tolerance(&idx, &pts, q).unwrap();
            // the building's answers are the same as without the segment
            assert_eq!(idx.correspondence(q), plain.correspondence(q));
            let q = [rng.range(-5001.0, -4989.0), rng.range(-3002.0, -2998.0)];
            within_tolerance(&idx, &pts, q).unwrap();
        }
    }

    #[test]
    fn a_grid_too_big_falls_back_to_exact_answers_and_says_so() {
        // 50 walls 30 m apart over 1.5 km × 1.5 km: far more than 2²³ cells at 2 cm
        let mut pts = Vec::new();
        for i in 0..50 {
            for k in 0..3000 {
                pts.push([i as f64 * 30.0, k as f64 * 0.5]);
            }
        }
        let idx = MapIndex::new(pts, None)
            .unwrap()
            .with_cache(Some(0.02))
            .unwrap();
        assert_eq!(idx.cache_resolution(), None);
        assert_eq!(idx.cache_bytes(), 0);
        let why = idx.cache_fallback().unwrap();
        assert!(
            why.contains("cache_resolution=0.02") && why.contains("exact"),
            "{why}"
        );
        let mut rng = crate::testkit::Rng::new(2);
        for _ in 0..200 {
            let q = [rng.range(0.0, 1500.0), rng.range(0.0, 1500.0)];
            assert_eq!(idx.correspondence(q), idx.nearest(q));
        }
    }

    #[test]
    fn coordinates_beyond_the_bound_are_an_error_naming_the_row() {
        let e = MapIndex::new(vec![[0.0, 0.0], [1.0, 1e154]], None).unwrap_err();
        assert_eq!(
            e,
            IcpError::InvalidInput {
                what: "map points".into(),
                reason: "row 1 (1e0, 1e154) is farther than 1e9 m from the origin (map \
                         coordinates are metres)"
                    .into()
            }
        );
        assert!(MapIndex::new(vec![[-1e9, 1e9]], None).is_ok());
    }

    #[test]
    fn extreme_queries_through_the_grid_never_panic() {
        let pts = vec![[1e9, -1e9], [1e9 - 1.0, -1e9]];
        let idx = MapIndex::new(pts.clone(), None)
            .unwrap()
            .with_cache(Some(0.02))
            .unwrap();
        assert_eq!(idx.cache_resolution(), Some(0.02));
        within_tolerance(&idx, &pts, [1e9 - 0.3, -1e9 + 0.2]).unwrap();
        for q in [
            [1e300, 1e300],
            [-1e308, 5.0],
            [f64::MAX, f64::MIN],
            [1e9, f64::MAX],
        ] {
            let (d2, j) = idx.correspondence(q);
            assert!(j < 2);
            assert_eq!(d2, f64::INFINITY);
        }
        let (d2, _) = idx.correspondence([f64::NAN, 0.0]);
        assert!(d2.is_nan());
    }

    #[test]
    fn single_point_map() {
        let idx = MapIndex::new(vec![[1.0, 2.0]], None).unwrap();
        assert_eq!(idx.nearest([0.0, 0.0]).1, 0);
        assert_eq!(idx.normals().len(), 1);
        assert_eq!(idx.spacing(), 0.0);
    }

    #[test]
    fn estimated_normals_are_perpendicular_to_walls() {
        let idx = MapIndex::new(wall_points(), None).unwrap();
        let n = idx.normals();
        for (p, v) in idx.points().iter().zip(n) {
            let len = (v[0] * v[0] + v[1] * v[1]).sqrt();
            assert!((len - 1.0).abs() < 1e-9);
            // interior of the bottom wall: normal along y
            if p[1] == 0.0 && p[0] > 0.3 && p[0] < 4.7 {
                assert!(v[0].abs() < 1e-6, "{p:?} {v:?}");
            }
        }
        assert!((idx.spacing() - 0.05).abs() < 1e-9);
    }

    #[test]
    fn visibility_hides_points_behind_a_wall() {
        // Room 0..5 with an inner wall at x = 3 from y = 1 to 4.
        let mut pts = wall_points();
        for i in 0..=60 {
            pts.push([3.0, 1.0 + i as f64 * 0.05]);
        }
        let idx = MapIndex::new(pts, None).unwrap();
        let pose = Pose2::new(1.0, 2.5, 0.0);
        let vis = idx
            .visible(pose, std::f64::consts::TAU, 30.0, None, 0.05, 0.002)
            .unwrap();
        let pts = idx.points();
        // the far wall x = 5 between y = 2 and 3 is hidden behind x = 3
        assert!(!vis
            .iter()
            .any(|&i| pts[i][0] == 5.0 && pts[i][1] > 2.0 && pts[i][1] < 3.0));
        // the inner wall's near face is visible, and so is the wall behind the robot
        assert!(vis
            .iter()
            .any(|&i| pts[i][0] == 3.0 && (pts[i][1] - 2.5).abs() < 0.1));
        assert!(vis
            .iter()
            .any(|&i| pts[i][0] == 0.0 && (pts[i][1] - 2.5).abs() < 0.1));
        // a 180° field of view facing +x excludes the wall behind
        let front = idx
            .visible(pose, std::f64::consts::PI, 30.0, None, 0.05, 0.002)
            .unwrap();
        assert!(!front
            .iter()
            .any(|&i| pts[i][0] == 0.0 && (pts[i][1] - 2.5).abs() < 1.0));
    }
}
