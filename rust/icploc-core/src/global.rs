//! Global localization: find the pose of a scan anywhere on the map, without a prior.
//!
//! Built once per map ([`GlobalLocalizer::new`]):
//!
//! * a distance field on a grid of `resolution` cells (distance from each cell centre to
//!   the closest map point, from the k-d tree),
//! * a likelihood grid `255·exp(−d²/2σ²)` (u8) and its max-pooled pyramid: level `h` holds,
//!   at cell (i, j), the maximum over the 2ʰ × 2ʰ window starting there,
//! * a free-space mask (cells at least `min_clearance` from every map point) and its
//!   "any free cell in the window" pyramid.
//!
//! One search ([`GlobalLocalizer::search`]) is a branch-and-bound correlative search in
//! the manner of Olson's multi-resolution scan matching and Cartographer's fast
//! correlative matcher: for every heading (a `angle_step` lattice, optionally restricted
//! to a range) the subsampled scan is rotated once into integer cell offsets; the
//! translations form a quadtree whose node bound is the sum of the pooled likelihood under
//! the points — an exact upper bound of every translation inside the node. Nodes are
//! explored depth-first (best child first) in parallel over roots, and pruned when their
//! bound falls below `accept_ratio` × the best leaf found so far (shared atomically) —
//! so every leaf within that ratio of the best survives, not just the best one, which is
//! what lets a symmetric or repetitive map show its alternatives. On a large region the
//! tree starts lower, at level [`DENSE_LEVEL`]: every node of that level summed at once,
//! heading by heading, row by row (the levels above it prune almost nothing on a large real
//! map and cost most of a whole-map search in random reads); the same leaves.
//!
//! The surviving leaves are thinned (non-maximum suppression) to `max_candidates` seeds,
//! each refined by point-to-line ICP ([`crate::icp::align`], in parallel) and re-scored on
//! the full scan against the k-d tree (a Gaussian likelihood of the point distances) times
//! one minus the fraction of beams that pass through a wall (negative information: the
//! laser cannot see through walls). Refined duplicates are merged and the candidates
//! ranked. The result is `ambiguous` when the best candidate and the best one distinct
//! from it (farther than `distinct_distance` or `distinct_angle`) score within
//! `ambiguity_margin` (relative) of each other: the caller must then confirm over the
//! next scans (odometry) rather than pick one.

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, OnceLock};

use rayon::prelude::*;

use crate::error::{IcpError, Result};
use crate::icp::{align, IcpConfig, Metric};
use crate::index::MapIndex;
use crate::likelihood::{pool, LikelihoodField};
use crate::se2::{wrap_angle, Pose2};

/// Settings of the global search. Distances in metres, angles in radians.
#[derive(Clone, Debug, PartialEq)]
pub struct GlobalConfig {
    /// Heading lattice step.
    pub angle_step: f64,
    /// Scan points used by the coarse search (evenly subsampled).
    pub max_points: usize,
    /// σ of the coarse likelihood grid (fixed when the localizer is built).
    pub sigma: f64,
    /// Candidate positions must be at least this far from every map point.
    pub min_clearance: f64,
    /// Keep every coarse leaf scoring at least this fraction of the best, in (0, 1].
    pub accept_ratio: f64,
    /// Coarse leaves below this fraction of a perfect score are never kept, in [0, 1).
    pub min_score: f64,
    /// Coarse seeds refined by ICP (after non-maximum suppression).
    pub max_candidates: usize,
    /// Non-maximum suppression of seeds: seeds closer than this (and `seed_angle`) merge.
    pub seed_distance: f64,
    pub seed_angle: f64,
    /// Pyramid depth: the coarsest node covers 2^levels × 2^levels cells.
    pub levels: usize,
    /// σ of the final (fine) likelihood.
    pub score_sigma: f64,
    /// A scan point closer than this to the map is an inlier.
    pub inlier_distance: f64,
    /// Two candidates are distinct when farther apart than this or `distinct_angle`.
    pub distinct_distance: f64,
    pub distinct_angle: f64,
    /// Relative score margin under which the best two distinct candidates are ambiguous.
    pub ambiguity_margin: f64,
    /// Refinement ICP.
    pub icp: IcpConfig,
}

impl Default for GlobalConfig {
    fn default() -> Self {
        Self {
            angle_step: 2f64.to_radians(),
            max_points: 96,
            sigma: 0.15,
            min_clearance: 0.2,
            accept_ratio: 0.8,
            min_score: 0.15,
            max_candidates: 32,
            seed_distance: 0.5,
            seed_angle: 10f64.to_radians(),
            levels: 6,
            score_sigma: 0.05,
            inlier_distance: 0.1,
            distinct_distance: 0.5,
            distinct_angle: 10f64.to_radians(),
            ambiguity_margin: 0.1,
            icp: IcpConfig {
                metric: Metric::PointToLine,
                max_iterations: 40,
                max_correspondence_distance: 0.6,
                min_correspondence_distance: 0.1,
                threshold_decay: 0.7,
                // the global search is the search: its refinement is plain ICP
                window_search: false,
                ..IcpConfig::default()
            },
        }
    }
}

fn bad(field: &'static str, value: impl ToString, reason: &'static str) -> IcpError {
    IcpError::InvalidConfig {
        field,
        value: value.to_string(),
        reason,
    }
}

impl GlobalConfig {
    /// Check every value; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let pos = |v: f64| v > 0.0 && v.is_finite();
        let nonneg = |v: f64| v >= 0.0 && v.is_finite();
        if !(pos(self.angle_step) && self.angle_step <= std::f64::consts::PI) {
            return Err(bad("angle_step", self.angle_step, "must be in (0, pi]"));
        }
        if self.max_points < 3 {
            return Err(bad("max_points", self.max_points, "must be at least 3"));
        }
        if !pos(self.sigma) {
            return Err(bad("sigma", self.sigma, "must be positive and finite"));
        }
        if !nonneg(self.min_clearance) {
            return Err(bad(
                "min_clearance",
                self.min_clearance,
                "must be non-negative and finite",
            ));
        }
        if !(self.accept_ratio > 0.0 && self.accept_ratio <= 1.0) {
            return Err(bad("accept_ratio", self.accept_ratio, "must be in (0, 1]"));
        }
        if !(0.0..1.0).contains(&self.min_score) {
            return Err(bad("min_score", self.min_score, "must be in [0, 1)"));
        }
        if self.max_candidates == 0 {
            return Err(bad("max_candidates", 0, "must be at least 1"));
        }
        if !nonneg(self.seed_distance) || !nonneg(self.seed_angle) {
            return Err(bad(
                "seed_distance",
                format!("{}, {}", self.seed_distance, self.seed_angle),
                "seed_distance and seed_angle must be non-negative and finite",
            ));
        }
        if self.levels > 12 {
            return Err(bad("levels", self.levels, "must be at most 12"));
        }
        if !pos(self.score_sigma) {
            return Err(bad(
                "score_sigma",
                self.score_sigma,
                "must be positive and finite",
            ));
        }
        if !pos(self.inlier_distance) {
            return Err(bad(
                "inlier_distance",
                self.inlier_distance,
                "must be positive and finite",
            ));
        }
        if !nonneg(self.distinct_distance) || !nonneg(self.distinct_angle) {
            return Err(bad(
                "distinct_distance",
                format!("{}, {}", self.distinct_distance, self.distinct_angle),
                "distinct_distance and distinct_angle must be non-negative and finite",
            ));
        }
        if !(0.0..1.0).contains(&self.ambiguity_margin) {
            return Err(bad(
                "ambiguity_margin",
                self.ambiguity_margin,
                "must be in [0, 1)",
            ));
        }
        self.icp.validate()
    }
}

/// One ranked pose hypothesis.
#[derive(Clone, Debug, PartialEq)]
pub struct Candidate {
    /// Sensor pose in the map frame (after ICP refinement).
    pub pose: Pose2,
    /// Final score in [0, 1]: mean Gaussian likelihood of the scan points' distances to the
    /// map, times one minus the fraction of beams passing through walls.
    pub score: f64,
    /// Fraction of scan points within `inlier_distance` of the map.
    pub inlier_ratio: f64,
    /// Mean-square distance of the inliers (m²).
    pub mse: f64,
    /// Fraction of the checked beams that pass through a wall before their return.
    pub see_through: f64,
    /// Coarse (grid) score of the seed, in [0, 1].
    pub coarse_score: f64,
}

/// The outcome of a search.
#[derive(Clone, Debug, PartialEq)]
pub struct GlobalResult {
    /// Best first; distinct (duplicates from different seeds are merged).
    pub candidates: Vec<Candidate>,
    /// The best two distinct candidates are too close in score to choose.
    pub ambiguous: bool,
    /// Quadtree nodes and leaves scored by the coarse search (on a large region: below
    /// the nodes of the level it starts from, those at the threshold counted).
    pub nodes: usize,
    /// Nodes of the level a search of a large region starts from, summed densely (all
    /// free ones in the region, every heading); 0 for a search from the top level.
    pub dense_nodes: usize,
    /// Coarse leaves within `accept_ratio` of the best.
    pub leaves: usize,
    /// Headings searched.
    pub headings: usize,
    /// Seconds spent in the coarse search and in refinement + scoring.
    pub coarse_time: f64,
    pub refine_time: f64,
}

impl GlobalResult {
    pub fn best(&self) -> Option<&Candidate> {
        self.candidates.first()
    }
}

/// A precomputed search structure for one map.
pub struct GlobalLocalizer {
    index: Arc<MapIndex>,
    cfg: GlobalConfig,
    /// The likelihood grid and its max-pooled pyramid.
    field: LikelihoodField,
    /// Pooled "some cell of the window is free".
    free: Vec<Vec<bool>>,
    /// The pyramid's level [`DENSE_LEVEL`] laid out for [`Self::dense_roots`], built on
    /// the first search that reads it.
    dense: OnceLock<DenseLevel>,
}

impl std::fmt::Debug for GlobalLocalizer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GlobalLocalizer")
            .field("resolution", &self.field.res)
            .field("origin", &(self.field.x0, self.field.y0))
            .field("cells", &(self.field.w, self.field.h))
            .field("levels", &self.field.pooled.len())
            .finish()
    }
}

#[derive(Clone, Copy)]
struct Node {
    bound: u32,
    level: u8,
    k: u32,
    i: i32,
    j: i32,
}

#[derive(Clone, Copy)]
struct Leaf {
    score: u32,
    k: u32,
    i: i32,
    j: i32,
}

impl GlobalLocalizer {
    /// Build the grids for `index` at `resolution` metres per cell.
    pub fn new(index: Arc<MapIndex>, resolution: f64, cfg: GlobalConfig) -> Result<Self> {
        cfg.validate()?;
        let field = LikelihoodField::build(&index, resolution, cfg.sigma, cfg.levels)?;
        Ok(Self::with_field(index, cfg, field))
    }

    /// hook (speed2, the likelihood-field cache): `new` from the field's distances
    /// ([`Self::distances`]) of an earlier `new` on the same map and resolution.
    pub fn from_distances(
        index: Arc<MapIndex>,
        resolution: f64,
        cfg: GlobalConfig,
        dist: Vec<f32>,
    ) -> Result<Self> {
        cfg.validate()?;
        let field =
            LikelihoodField::from_distances(&index, resolution, cfg.sigma, cfg.levels, dist)?;
        Ok(Self::with_field(index, cfg, field))
    }

    /// The likelihood field's distances (m, cell centre to map, row by row).
    pub fn distances(&self) -> &[f32] {
        self.field.distances()
    }

    fn with_field(index: Arc<MapIndex>, cfg: GlobalConfig, field: LikelihoodField) -> Self {
        let (w, h) = field.shape();
        let free0: Vec<bool> = field
            .dist
            .par_iter()
            .with_min_len(4096)
            .map(|&d| d as f64 >= cfg.min_clearance)
            .collect();
        let mut free = vec![free0];
        for lvl in 1..=cfg.levels {
            let next = pool(&free[lvl - 1], w, h, 1usize << (lvl - 1), |a, b| a | b);
            free.push(next);
        }
        Self {
            index,
            cfg,
            field,
            free,
            dense: OnceLock::new(),
        }
    }

    pub fn config(&self) -> &GlobalConfig {
        &self.cfg
    }

    pub fn index(&self) -> &Arc<MapIndex> {
        &self.index
    }

    pub fn resolution(&self) -> f64 {
        self.field.res
    }

    /// Grid size in cells (width, height).
    pub fn shape(&self) -> (usize, usize) {
        (self.field.w, self.field.h)
    }

    /// Number of grid cells where a pose may be (clearance from the map).
    pub fn free_cells(&self) -> usize {
        self.free[0].iter().filter(|&&f| f).count()
    }

    /// Distance (m) from `p` to the map as stored in the grid (nearest cell); `None`
    /// outside the grid.
    pub fn distance_at(&self, p: [f64; 2]) -> Option<f64> {
        self.field.distance_at(p)
    }

    /// Search the whole map (or `region` = (xmin, ymin, xmax, ymax) of the sensor
    /// position, and `heading` = (min, max) radians, min ≤ max, at most 2π wide) for the
    /// pose of `scan` (sensor-frame points).
    pub fn search(
        &self,
        scan: &[[f64; 2]],
        region: Option<[f64; 4]>,
        heading: Option<(f64, f64)>,
    ) -> Result<GlobalResult> {
        self.search_above(scan, region, heading, None)
    }

    /// [`Self::search`] with this search's own coarse floor: `min_score` (in [0, 1), the
    /// coarse score as a fraction of perfect) in place of the configured `min_score`. A
    /// caller that only cares about poses scoring above some level (a check for a place
    /// clearly better than a known one) prunes the tree from the start: the leaves are
    /// exactly those of [`Self::search`] at or above the floor.
    pub fn search_above(
        &self,
        scan: &[[f64; 2]],
        region: Option<[f64; 4]>,
        heading: Option<(f64, f64)>,
        min_score: Option<f64>,
    ) -> Result<GlobalResult> {
        crate::check_finite("scan", scan)?;
        if let Some(f) = min_score {
            if !(0.0..1.0).contains(&f) {
                return Err(IcpError::InvalidInput {
                    what: "min_score".into(),
                    reason: format!("must be in [0, 1), got {f}"),
                });
            }
        }
        let floor_score = min_score.unwrap_or(self.cfg.min_score);
        let t0 = std::time::Instant::now();
        let cfg = &self.cfg;
        let usable: Vec<[f64; 2]> = scan
            .iter()
            .copied()
            .filter(|p| p[0] * p[0] + p[1] * p[1] > 1e-12)
            .collect();
        if usable.len() < cfg.icp.min_inliers.max(3) {
            return Err(IcpError::TooFewPoints {
                what: "scan".into(),
                got: usable.len(),
                min: cfg.icp.min_inliers.max(3),
            });
        }
        // region in cells (inclusive)
        let (ri0, rj0, ri1, rj1) = match region {
            None => (0i32, 0i32, self.field.w as i32 - 1, self.field.h as i32 - 1),
            Some(r) => {
                if !r.iter().all(|v| v.is_finite()) || r[0] > r[2] || r[1] > r[3] {
                    return Err(IcpError::InvalidInput {
                        what: "region".into(),
                        reason: format!(
                            "must be finite (xmin, ymin, xmax, ymax) with xmin <= xmax and ymin <= ymax, got {r:?}"
                        ),
                    });
                }
                let (fx0, fy0, res) = (self.field.x0, self.field.y0, self.field.res);
                let (wmax, hmax) = (self.field.w as f64 - 1.0, self.field.h as f64 - 1.0);
                let mut i0 = ((r[0] - fx0) / res).ceil().max(0.0);
                let mut j0 = ((r[1] - fy0) / res).ceil().max(0.0);
                let mut i1 = ((r[2] - fx0) / res).floor().min(wmax);
                let mut j1 = ((r[3] - fy0) / res).floor().min(hmax);
                // a region narrower than a cell, between two cell centres (a window clipped
                // to a sliver at the map's edge): the cells whose footprint it overlaps
                if i0 > i1 {
                    i0 = ((r[0] - fx0) / res - 0.5).ceil().max(0.0);
                    i1 = ((r[2] - fx0) / res + 0.5).floor().min(wmax);
                }
                if j0 > j1 {
                    j0 = ((r[1] - fy0) / res - 0.5).ceil().max(0.0);
                    j1 = ((r[3] - fy0) / res + 0.5).floor().min(hmax);
                }
                if i0 > i1 || j0 > j1 {
                    return Err(IcpError::InvalidInput {
                        what: "region".into(),
                        reason: format!("{r:?} does not overlap the map grid"),
                    });
                }
                (i0 as i32, j0 as i32, i1 as i32, j1 as i32)
            }
        };
        let headings: Vec<f64> = match heading {
            None => {
                let n = (std::f64::consts::TAU / cfg.angle_step).round().max(1.0) as usize;
                let step = std::f64::consts::TAU / n as f64;
                (0..n).map(|k| wrap_angle(k as f64 * step)).collect()
            }
            Some((lo, hi)) => {
                if !(lo.is_finite() && hi.is_finite() && lo <= hi)
                    || hi - lo > std::f64::consts::TAU + 1e-9
                {
                    return Err(IcpError::InvalidInput {
                        what: "heading".into(),
                        reason: format!(
                            "must be finite (min, max) with min <= max <= min + 2 pi, got ({lo}, {hi})"
                        ),
                    });
                }
                let n = ((hi - lo) / cfg.angle_step).ceil().max(0.0) as usize + 1;
                let step = if n > 1 {
                    (hi - lo) / (n - 1) as f64
                } else {
                    0.0
                };
                (0..n).map(|k| wrap_angle(lo + k as f64 * step)).collect()
            }
        };
        // subsample the scan evenly
        let m = usable.len().min(cfg.max_points);
        let sub: Vec<[f64; 2]> = (0..m).map(|k| usable[k * usable.len() / m]).collect();
        let offsets = cell_offsets(&sub, headings.iter().copied(), self.field.res);
        let full = 255 * m as u32;
        let Coarse {
            mut leaves,
            nodes,
            dense: dense_nodes,
        } = self.coarse(&offsets, [ri0, rj0, ri1, rj1], m, floor_score);
        let n_leaves = leaves.len();
        // ties broken by position: the seeds (and the result) do not depend on thread timing
        leaves.sort_unstable_by_key(|l| (std::cmp::Reverse(l.score), l.k, l.j, l.i));
        // non-maximum suppression into seeds
        let mut seeds: Vec<(Pose2, f64)> = Vec::new();
        for l in &leaves {
            let p = Pose2::new(
                self.field.x0 + l.i as f64 * self.field.res,
                self.field.y0 + l.j as f64 * self.field.res,
                headings[l.k as usize],
            );
            let close = seeds.iter().any(|(q, _)| {
                (p.x - q.x).hypot(p.y - q.y) <= cfg.seed_distance
                    && wrap_angle(p.theta - q.theta).abs() <= cfg.seed_angle
            });
            if !close {
                seeds.push((p, l.score as f64 / full as f64));
                if seeds.len() >= cfg.max_candidates {
                    break;
                }
            }
        }
        let coarse_time = t0.elapsed().as_secs_f64();
        // refine and re-score
        let mut cands: Vec<Candidate> = seeds
            .par_iter()
            .with_max_len(1)
            .filter_map(|&(p, coarse)| {
                let r = align(&usable, &self.index, p, &cfg.icp).ok()?;
                if !r.pose.is_finite() {
                    return None;
                }
                let pose = r.pose.normalized();
                // refinement may slide a seed into a wall or off the grid: not a pose
                let clear = self.distance_at([pose.x, pose.y])?;
                if clear < 0.5 * cfg.min_clearance {
                    return None;
                }
                Some(self.score_pose(&usable, pose, coarse))
            })
            .collect();
        cands.sort_by(|a, b| b.score.total_cmp(&a.score));
        let mut merged: Vec<Candidate> = Vec::new();
        for c in cands {
            let dup = merged.iter().any(|q| {
                (c.pose.x - q.pose.x).hypot(c.pose.y - q.pose.y) <= 0.1
                    && wrap_angle(c.pose.theta - q.pose.theta).abs() <= 2f64.to_radians()
            });
            if !dup {
                merged.push(c);
            }
        }
        let ambiguous = match merged.first() {
            None => false,
            Some(b) => merged[1..]
                .iter()
                .find(|c| self.distinct(&b.pose, &c.pose))
                .is_some_and(|c| c.score >= b.score * (1.0 - cfg.ambiguity_margin)),
        };
        Ok(GlobalResult {
            candidates: merged,
            ambiguous,
            nodes,
            dense_nodes,
            leaves: n_leaves,
            headings: headings.len(),
            coarse_time,
            refine_time: t0.elapsed().as_secs_f64() - coarse_time,
        })
    }

    /// Refine each of `poses` by ICP (the search's refinement settings, in parallel) and
    /// score the result like a search candidate (`coarse_score` 0). A pose whose ICP fails
    /// is scored where it stands. For tracking hypotheses from scan to scan.
    pub fn refine(&self, scan: &[[f64; 2]], poses: &[Pose2]) -> Result<Vec<Candidate>> {
        crate::check_finite("scan", scan)?;
        self.check_poses(poses)?;
        if scan.len() < self.cfg.icp.min_inliers.max(3) {
            return Err(IcpError::TooFewPoints {
                what: "scan".into(),
                got: scan.len(),
                min: self.cfg.icp.min_inliers.max(3),
            });
        }
        Ok(poses
            .par_iter()
            .with_max_len(1)
            .map(|&p| {
                let q = align(scan, &self.index, p, &self.cfg.icp)
                    .ok()
                    .map(|r| r.pose.normalized())
                    .filter(|q| q.is_finite())
                    .unwrap_or(p);
                self.score_pose(scan, q, 0.0)
            })
            .collect())
    }

    /// Score `scan` at each of `poses` (no refinement).
    pub fn score(&self, scan: &[[f64; 2]], poses: &[Pose2]) -> Result<Vec<Candidate>> {
        crate::check_finite("scan", scan)?;
        self.check_poses(poses)?;
        Ok(poses
            .par_iter()
            .map(|&p| self.score_pose(scan, p, 0.0))
            .collect())
    }

    fn check_poses(&self, poses: &[Pose2]) -> Result<()> {
        match poses.iter().position(|p| !p.is_finite()) {
            Some(row) => Err(IcpError::NonFinite {
                what: "poses".into(),
                row,
            }),
            None => Ok(()),
        }
    }

    /// Are two poses distinct hypotheses (farther apart than `distinct_distance` or
    /// `distinct_angle`)?
    pub fn distinct(&self, a: &Pose2, b: &Pose2) -> bool {
        (a.x - b.x).hypot(a.y - b.y) > self.cfg.distinct_distance
            || wrap_angle(a.theta - b.theta).abs() > self.cfg.distinct_angle
    }

    /// Score `scan` (sensor frame) at `pose` exactly (k-d tree) with the see-through
    /// penalty; `coarse` is copied into the result.
    pub fn score_pose(&self, scan: &[[f64; 2]], pose: Pose2, coarse: f64) -> Candidate {
        let cfg = &self.cfg;
        let inv2s2 = 1.0 / (2.0 * cfg.score_sigma * cfg.score_sigma);
        let il2 = cfg.inlier_distance * cfg.inlier_distance;
        let (mut lik, mut inl, mut sq) = (0.0, 0usize, 0.0);
        let mut n = 0usize;
        for p in scan {
            let q = pose.transform(*p);
            if !(q[0].is_finite() && q[1].is_finite()) {
                continue;
            }
            n += 1;
            let d2 = self.index.nearest(q).0;
            lik += (-d2 * inv2s2).exp();
            if d2 <= il2 {
                inl += 1;
                sq += d2;
            }
        }
        let see_through = self.see_through(scan, pose);
        let n = n.max(1) as f64;
        Candidate {
            pose,
            score: (lik / n) * (1.0 - see_through),
            inlier_ratio: inl as f64 / n,
            mse: if inl > 0 { sq / inl as f64 } else { 0.0 },
            see_through,
            coarse_score: coarse,
        }
    }

    /// Fraction of the beams (sensor origin to each scan point) that pass through a mapped
    /// wall more than 0.3 m before the return. A beam that only grazes a wall (meets it at
    /// less than ~15 degrees, as along a corridor) does not count: on a grid it cannot be
    /// told from a beam passing just beside the wall.
    pub fn see_through(&self, scan: &[[f64; 2]], pose: Pose2) -> f64 {
        let step = self.field.res;
        let spacing = self.index.spacing();
        let thr = 0.5 * spacing + 0.5 * step + 0.75 * self.field.res;
        let margin = 0.3f64.max(3.0 * self.cfg.inlier_distance);
        let normals = self.index.normals();
        let min_sin = 15f64.to_radians().sin();
        let (mut checked, mut bad) = (0usize, 0usize);
        for p in scan {
            let r = p[0].hypot(p[1]);
            if r <= 2.0 * margin || !r.is_finite() {
                continue;
            }
            checked += 1;
            let q = pose.transform(*p);
            let (dx, dy) = ((q[0] - pose.x) / r, (q[1] - pose.y) / r);
            let mut t = margin;
            while t < r - margin {
                let s = [pose.x + dx * t, pose.y + dy * t];
                if let Some(d) = self.distance_at(s) {
                    if d < thr
                        && self.crosses(
                            s,
                            [s[0] - dx * step, s[1] - dy * step],
                            [dx, dy],
                            normals,
                            min_sin,
                        )
                    {
                        bad += 1;
                        break;
                    }
                }
                t += step;
            }
        }
        if checked == 0 {
            0.0
        } else {
            bad as f64 / checked as f64
        }
    }

    /// Does the ray step `prev -> s` (direction `dir`) cross the wall of the map point
    /// nearest to `s` — the line through it along its normal changes side, at a point on
    /// the wall (not past its end: a beam through a doorway near the jamb), at more than
    /// the grazing angle?
    fn crosses(
        &self,
        s: [f64; 2],
        prev: [f64; 2],
        dir: [f64; 2],
        normals: &[[f64; 2]],
        min_sin: f64,
    ) -> bool {
        let j = self.index.nearest(s).1;
        let (p, n) = (self.index.points()[j], normals[j]);
        let cos = dir[0] * n[0] + dir[1] * n[1];
        if cos.abs() < min_sin {
            return false;
        }
        let s1 = (s[0] - p[0]) * n[0] + (s[1] - p[1]) * n[1];
        let s0 = (prev[0] - p[0]) * n[0] + (prev[1] - p[1]) * n[1];
        if s0 * s1 > 0.0 {
            // both on one side: crossed only if the next step does (checked then), unless
            // the step is already on the wall's line
            return s1.abs() < 1e-9;
        }
        let f = if (s0 - s1).abs() > 1e-12 {
            s0 / (s0 - s1)
        } else {
            0.0
        };
        let c = [
            prev[0] + f * (s[0] - prev[0]),
            prev[1] + f * (s[1] - prev[1]),
        ];
        // on the wall: a map point within ~half the sampling interval of the crossing
        // point (measured from the crossing itself: the point nearest to `s` can be a
        // step away along the wall on a densely sampled map)
        self.index.nearest(c).0.sqrt() <= 0.75 * self.index.spacing() + 0.005
    }
}

/// The scan's points `sub` rotated by each heading and floored to cells of size `res`:
/// one offset list per heading, as the coarse search slides them over the pyramid.
fn cell_offsets(
    sub: &[[f64; 2]],
    headings: impl Iterator<Item = f64>,
    res: f64,
) -> Vec<Vec<(i32, i32)>> {
    let inv = 1.0 / res;
    headings
        .map(|th| {
            let (s, c) = th.sin_cos();
            sub.iter()
                .map(|p| {
                    let x = c * p[0] - s * p[1];
                    let y = s * p[0] + c * p[1];
                    ((x * inv).floor() as i32, (y * inv).floor() as i32)
                })
                .collect()
        })
        .collect()
}

/// The bounds of the four children of a node at (`i`, `j`), at (i, j), (i + s, j),
/// (i, j + s) and (i + s, j + s) with s = 2^`level`, in one pass over the points: each
/// the value [`LikelihoodField::sum`] gives for it at `level` (where all four cells of a
/// point are inside the grid they are read from one base index; elsewhere by its rule).
#[cfg(test)]
fn child_sums(f: &LikelihoodField, level: usize, offs: &[(i32, i32)], i: i32, j: i32) -> [u32; 4] {
    let g = &f.pooled[level];
    let (w, h) = (f.w as i32, f.h as i32);
    let s = 1i32 << level;
    let lo = 1 - s;
    let sw = (s * w) as usize;
    let su = s as usize;
    let mut out = [0u32; 4];
    let at = |x: i32, y: i32| -> u32 {
        if x >= lo && y >= lo && x < w && y < h {
            g[(y.max(0) * w + x.max(0)) as usize] as u32
        } else {
            0
        }
    };
    for &(ox, oy) in offs {
        let (x, y) = (i + ox, j + oy);
        if x >= 0 && y >= 0 && x + s < w && y + s < h {
            let c = (y * w + x) as usize;
            out[0] += g[c] as u32;
            out[1] += g[c + su] as u32;
            out[2] += g[c + sw] as u32;
            out[3] += g[c + sw + su] as u32;
        } else {
            out[0] += at(x, y);
            out[1] += at(x + s, y);
            out[2] += at(x, y + s);
            out[3] += at(x + s, y + s);
        }
    }
    out
}

/// One heading's cell offsets as the coarse search reads them: the offsets, the same as
/// row-major index offsets in a grid `w` wide, and their bounding box.
pub(crate) struct Shifts<'a> {
    offs: &'a [(i32, i32)],
    lin: Vec<isize>,
    /// (min x, min y, max x, max y) of `offs`
    bbox: [i32; 4],
}

impl<'a> Shifts<'a> {
    pub(crate) fn new(offs: &'a [(i32, i32)], w: usize) -> Self {
        let lin = offs
            .iter()
            .map(|&(x, y)| y as isize * w as isize + x as isize)
            .collect();
        let mut bbox = [i32::MAX, i32::MAX, i32::MIN, i32::MIN];
        for &(x, y) in offs {
            bbox = [
                bbox[0].min(x),
                bbox[1].min(y),
                bbox[2].max(x),
                bbox[3].max(y),
            ];
        }
        Self { offs, lin, bbox }
    }
}

/// [`child_sums`] with one test per node instead of one per point where all four cells of
/// every point lie inside the grid (most nodes of a large map): the same sums (the core's
/// window search reads these; [`child_sums_above`] with no threshold never exits early).
#[inline]
pub(crate) fn child_sums_shifted(
    f: &LikelihoodField,
    level: usize,
    sh: &Shifts,
    i: i32,
    j: i32,
) -> [u32; 4] {
    child_sums_above(f, level, sh, i, j, u32::MAX, 0).expect("a floor of 0 is always met")
}

/// Scan points summed between two checks of [`child_sums_above`]'s early exit.
const EXIT_CHUNK: usize = 16;

/// [`child_sums`] of the node at (`i`, `j`) one level above `level` whose bound is `bound`,
/// or `None` when every child's sum is below `thr` (the search drops them all). With one
/// test per node instead of one per point where all four cells of every point lie inside
/// the grid (most nodes of a large map), and there the early exit: the node's bound is,
/// point by point, at least the largest of the four children's values (its pooled window
/// covers theirs; inside the grid, where the pooling is exact, equal), so after the first
/// points each child's sum is at most its partial sum plus what of the bound the largest
/// values of those points have not used up; when that is below `thr` for all four, their
/// sums are too. After the last point that remainder is 0 for a node's exact bound: then
/// `None` exactly when all four sums are below `thr`.
#[inline]
fn child_sums_above(
    f: &LikelihoodField,
    level: usize,
    sh: &Shifts,
    i: i32,
    j: i32,
    bound: u32,
    thr: u32,
) -> Option<[u32; 4]> {
    let s = 1i32 << level;
    let [x0, y0, x1, y1] = sh.bbox;
    let (w, h) = (f.w as i32, f.h as i32);
    if sh.offs.is_empty() || i + x0 < 0 || j + y0 < 0 || i + x1 + s >= w || j + y1 + s >= h {
        return child_sums_clipped(f, level, sh.offs, i, j, bound, thr);
    }
    let g = &f.pooled[level];
    let base = j as isize * f.w as isize + i as isize;
    let (su, sw) = (s as usize, s as usize * f.w);
    let mut out = [0u32; 4];
    // the sum over the points so far of the largest of the four values
    let mut used = 0u32;
    for chunk in sh.lin.chunks(EXIT_CHUNK) {
        for &l in chunk {
            let c = (base + l) as usize;
            add_four(
                &mut out,
                &mut used,
                [g[c], g[c + su], g[c + sw], g[c + sw + su]],
            );
        }
        if cannot_reach(&out, used, bound, thr) {
            return None;
        }
    }
    Some(out)
}

/// [`child_sums_above`] of a node some of whose points' cells lie outside the grid: the
/// points one by one, each cell read by [`LikelihoodField::sum`]'s rule (a window that
/// starts left of / below the grid but overlaps it reads the window at 0, one wholly
/// outside reads 0), with the same early exit. It holds here too: under that rule a
/// point's value at the parent's level still bounds its four values at the children's
/// (each child's window, clipped to the grid, lies in the parent's clipped window, and
/// a child window wholly outside reads 0), so `bound` minus the largest values summed so
/// far bounds what the remaining points can add to any child. After the last point:
/// `None` exactly when all four sums are below `thr`, whatever `bound`.
#[inline]
fn child_sums_clipped(
    f: &LikelihoodField,
    level: usize,
    offs: &[(i32, i32)],
    i: i32,
    j: i32,
    bound: u32,
    thr: u32,
) -> Option<[u32; 4]> {
    let g = &f.pooled[level];
    let (w, h) = (f.w as i32, f.h as i32);
    let s = 1i32 << level;
    let lo = 1 - s;
    let sw = (s * w) as usize;
    let su = s as usize;
    let at = |x: i32, y: i32| -> u8 {
        if x >= lo && y >= lo && x < w && y < h {
            g[(y.max(0) * w + x.max(0)) as usize]
        } else {
            0
        }
    };
    let mut out = [0u32; 4];
    let mut used = 0u32;
    for chunk in offs.chunks(EXIT_CHUNK) {
        for &(ox, oy) in chunk {
            let (x, y) = (i + ox, j + oy);
            let v = if x >= 0 && y >= 0 && x + s < w && y + s < h {
                let c = (y * w + x) as usize;
                [g[c], g[c + su], g[c + sw], g[c + sw + su]]
            } else {
                [at(x, y), at(x + s, y), at(x, y + s), at(x + s, y + s)]
            };
            add_four(&mut out, &mut used, v);
        }
        if cannot_reach(&out, used, bound, thr) {
            return None;
        }
    }
    (out[0].max(out[1]).max(out[2].max(out[3])) >= thr).then_some(out)
}

/// One point's values at a node's four children added to their sums, and the largest of
/// them to `used` (what the point could add to any one child).
#[inline(always)]
fn add_four(out: &mut [u32; 4], used: &mut u32, v: [u8; 4]) {
    out[0] += v[0] as u32;
    out[1] += v[1] as u32;
    out[2] += v[2] as u32;
    out[3] += v[3] as u32;
    *used += v[0].max(v[1]).max(v[2].max(v[3])) as u32;
}

/// The early exit of the child sums: even if every point not yet summed added its share of
/// the parent's `bound` (`bound` minus the largest values summed so far) to the best child,
/// it would stay below `thr`.
#[inline(always)]
fn cannot_reach(out: &[u32; 4], used: u32, bound: u32, thr: u32) -> bool {
    let top = out[0].max(out[1]).max(out[2].max(out[3]));
    top.saturating_add(bound.saturating_sub(used)) < thr
}

/// The pyramid level the coarse search starts from on a large region (the two to three
/// levels above it prune almost nothing on a large real map, where the pooled likelihood
/// under most points is high over a 1-3 m window: they only cost random reads).
const DENSE_LEVEL: usize = 3;

/// Below this many nodes of the dense level in a search's region (and headings), the
/// search starts from its top level's nodes as before (a small window: a few roots).
const DENSE_MIN_NODES: usize = 4096;

/// One heading's share of a dense start: the dense level, the region's rows (first and
/// last free node of each), the heading's point offsets and index, and the search's tree.
#[derive(Clone, Copy)]
struct DenseJob<'a> {
    d: &'a DenseLevel,
    rows: &'a [(i32, i32)],
    offs: &'a [(i32, i32)],
    k: u32,
    tree: &'a Tree<'a>,
}

/// One level `L` of the likelihood pyramid laid out for reading the value under one scan
/// point at every node of the level's lattice (cells (a·2ᴸ, b·2ᴸ)) as contiguous rows: a
/// plane per residue (rx, ry) in [0, 2ᴸ)², holding at row `b + 1`, column `a + 1` the value
/// [`LikelihoodField::sum`] reads at cell (a·2ᴸ + rx, b·2ᴸ + ry), for a in [-1, nx) and b in
/// [-1, ny) (row and column -1: the windows that start left of / below the grid; a cell
/// wholly outside the grid reads 0). The same bytes as the level, once more.
struct DenseLevel {
    level: usize,
    /// Lattice nodes across and up: ceil(w / 2ᴸ), ceil(h / 2ᴸ).
    nx: i32,
    ny: i32,
    /// Row length (nx + 1) and plane size ((nx + 1)(ny + 1)).
    stride: usize,
    plane: usize,
    cells: Vec<u8>,
}

impl DenseLevel {
    fn build(f: &LikelihoodField, level: usize) -> Self {
        let g = &f.pooled[level];
        let (w, h) = (f.w as i32, f.h as i32);
        let s = 1i32 << level;
        let lo = 1 - s;
        let (nx, ny) = ((w + s - 1) / s, (h + s - 1) / s);
        let stride = nx as usize + 1;
        let plane = stride * (ny as usize + 1);
        let mut cells = vec![0u8; plane * (s * s) as usize];
        cells.par_chunks_mut(plane).enumerate().for_each(|(r, pl)| {
            let (rx, ry) = (r as i32 % s, r as i32 / s);
            for b in -1..ny {
                let y = b * s + ry;
                if y < lo || y >= h {
                    continue;
                }
                let src = &g[(y.max(0) * w) as usize..][..w as usize];
                let dst = &mut pl[(b + 1) as usize * stride..][..stride];
                for (a, d) in (-1..nx).zip(dst.iter_mut()) {
                    let x = a * s + rx;
                    if x >= lo && x < w {
                        *d = src[x.max(0) as usize];
                    }
                }
            }
        });
        Self {
            level,
            nx,
            ny,
            stride,
            plane,
            cells,
        }
    }

    /// The start of the plane of residue (rx, ry).
    fn plane_of(&self, rx: i32, ry: i32) -> usize {
        (ry * (1i32 << self.level) + rx) as usize * self.plane
    }
}

/// Whether this CPU has AVX2 (checked once).
#[cfg(target_arch = "x86_64")]
fn has_avx2() -> bool {
    static AVX2: OnceLock<bool> = OnceLock::new();
    *AVX2.get_or_init(|| std::arch::is_x86_feature_detected!("avx2"))
}

/// The per-node part of the branch-and-bound, shared by its workers.
struct Tree<'a> {
    g: &'a GlobalLocalizer,
    shifts: &'a [Shifts<'a>],
    region: [i32; 4],
    floor: u32,
    best: &'a AtomicU32,
}

impl Tree<'_> {
    fn threshold(&self) -> u32 {
        let b = self.best.load(Ordering::Relaxed);
        (((b as f64) * self.g.cfg.accept_ratio).ceil() as u32).max(self.floor)
    }

    fn in_region(&self, lvl: usize, i: i32, j: i32) -> bool {
        let [ri0, rj0, ri1, rj1] = self.region;
        let e = (1i32 << lvl) - 1;
        i <= ri1 && i + e >= ri0 && j <= rj1 && j + e >= rj0
    }

    /// A level-0 node that has reached the threshold: a leaf.
    fn leaf(&self, n: &Node, leaves: &mut Vec<Leaf>) {
        leaves.push(Leaf {
            score: n.bound,
            k: n.k,
            i: n.i,
            j: n.j,
        });
        self.best.fetch_max(n.bound, Ordering::Relaxed);
    }

    /// Depth-first below `root` (best child first), pruning at the threshold of the
    /// moment; the leaves go to `leaves`, the count of nodes scored to `nodes`.
    fn descend(
        &self,
        root: Node,
        leaves: &mut Vec<Leaf>,
        nodes: &mut usize,
        stack: &mut Vec<Node>,
    ) {
        let field = &self.g.field;
        let free = &self.g.free;
        let [ri0, rj0, ri1, rj1] = self.region;
        stack.clear();
        stack.push(root);
        while let Some(n) = stack.pop() {
            let thr = self.threshold();
            if n.bound < thr {
                continue;
            }
            if n.level == 0 {
                self.leaf(&n, leaves);
                continue;
            }
            let lvl = n.level as usize - 1;
            let s = 1i32 << lvl;
            // None: every child is below the threshold (scored, and dropped)
            let sums = child_sums_above(
                field,
                lvl,
                &self.shifts[n.k as usize],
                n.i,
                n.j,
                n.bound,
                thr,
            )
            .unwrap_or([0; 4]);
            let mut kids: [Node; 4] = [n; 4];
            let mut nk = 0;
            for (c, (a, b)) in [(0, 0), (s, 0), (0, s), (s, s)].into_iter().enumerate() {
                let (ci, cj) = (n.i + a, n.j + b);
                if ci >= field.w as i32 || cj >= field.h as i32 {
                    continue;
                }
                let ok = if lvl == 0 {
                    ci >= ri0
                        && ci <= ri1
                        && cj >= rj0
                        && cj <= rj1
                        && free[0][cj as usize * field.w + ci as usize]
                } else {
                    self.in_region(lvl, ci, cj) && free[lvl][cj as usize * field.w + ci as usize]
                };
                if !ok {
                    continue;
                }
                *nodes += 1;
                let bound = sums[c];
                if bound < thr {
                    continue;
                }
                let kid = Node {
                    bound,
                    level: lvl as u8,
                    k: n.k,
                    i: ci,
                    j: cj,
                };
                if lvl == 0 {
                    // the bound is the exact score at level 0
                    self.leaf(&kid, leaves);
                    continue;
                }
                kids[nk] = kid;
                nk += 1;
            }
            let kids = &mut kids[..nk];
            kids.sort_unstable_by_key(|c| c.bound);
            stack.extend_from_slice(kids);
        }
    }
}

/// What the coarse search found: the leaves, the tree's nodes scored and the dense
/// level's nodes summed.
struct Coarse {
    leaves: Vec<Leaf>,
    nodes: usize,
    dense: usize,
}

impl GlobalLocalizer {
    /// The coarse branch-and-bound of [`Self::search`]: every level-0 leaf (heading `k`,
    /// cell (i, j)) in `region` (cells, inclusive) on a free cell whose score is at least
    /// `accept_ratio` x the best leaf's (and at least `min_score` x perfect), with the
    /// number of nodes evaluated. A node is dropped only when its bound (an upper bound of
    /// all its leaves) is below `accept_ratio` x the best leaf found so far, so the leaves
    /// are exactly those whatever the order of the search.
    #[cfg(test)]
    fn coarse_leaves(
        &self,
        offsets: &[Vec<(i32, i32)>],
        region: [i32; 4],
        m: usize,
        min_score: f64,
    ) -> (Vec<Leaf>, usize) {
        let c = self.coarse(offsets, region, m, min_score);
        (c.leaves, c.nodes)
    }

    /// [`Self::coarse_leaves`]: on a large region the tree starts from the nodes of
    /// [`DENSE_LEVEL`] (every node of that level in the region summed at once, row by row,
    /// [`Self::dense_roots`]), else from the top level's nodes. The same leaves either way:
    /// a node of the dense level gets the bound its parent's [`child_sums_above`] would
    /// give it, and any of its ancestors bounds it.
    fn coarse(
        &self,
        offsets: &[Vec<(i32, i32)>],
        region: [i32; 4],
        m: usize,
        min_score: f64,
    ) -> Coarse {
        let lvl = DENSE_LEVEL.min(self.cfg.levels);
        let [ri0, rj0, ri1, rj1] = region;
        let span =
            |lo: i32, hi: i32| (hi.div_euclid(1 << lvl) - lo.div_euclid(1 << lvl) + 1) as usize;
        let dense_nodes = span(ri0, ri1) * span(rj0, rj1) * offsets.len();
        // the dense rows sum in u16
        let dense = dense_nodes >= DENSE_MIN_NODES && 255 * m <= u16::MAX as usize;
        self.coarse_from(offsets, region, m, min_score, dense.then_some(lvl))
    }

    /// The coarse search from the nodes of level `dense` summed densely, or (None) from the
    /// top level's nodes.
    fn coarse_from(
        &self,
        offsets: &[Vec<(i32, i32)>],
        region: [i32; 4],
        m: usize,
        min_score: f64,
        dense: Option<usize>,
    ) -> Coarse {
        let shifts: Vec<Shifts> = offsets
            .iter()
            .map(|o| Shifts::new(o, self.field.w))
            .collect();
        let full = 255 * m as u32;
        let floor = (min_score * full as f64).ceil() as u32;
        let best = AtomicU32::new(floor);
        let tree = Tree {
            g: self,
            shifts: &shifts,
            region,
            floor,
            best: &best,
        };
        let (leaves, nodes, summed) = match dense {
            None => self.start_at_top(&tree, offsets),
            Some(lvl) => self.start_dense(&tree, offsets, lvl),
        };
        let keep = tree.threshold();
        Coarse {
            leaves: leaves.into_iter().filter(|l| l.score >= keep).collect(),
            nodes,
            dense: summed,
        }
    }

    /// The roots: the coarsest level's nodes of every heading, scored one by one; explored
    /// in parallel, best bound first.
    fn start_at_top(&self, tree: &Tree, offsets: &[Vec<(i32, i32)>]) -> (Vec<Leaf>, usize, usize) {
        let top = self.cfg.levels;
        let stride = 1i32 << top;
        let [ri0, rj0, ri1, rj1] = tree.region;
        let mut roots: Vec<Node> = Vec::new();
        let mut j = (rj0 / stride) * stride;
        while j <= rj1 {
            let mut i = (ri0 / stride) * stride;
            while i <= ri1 {
                if self.free[top][(j as usize) * self.field.w + i as usize]
                    && tree.in_region(top, i, j)
                {
                    for k in 0..offsets.len() {
                        roots.push(Node {
                            bound: 0,
                            level: top as u8,
                            k: k as u32,
                            i,
                            j,
                        });
                    }
                }
                i += stride;
            }
            j += stride;
        }
        roots.par_iter_mut().for_each(|n| {
            n.bound = self.field.sum(top, &offsets[n.k as usize], n.i, n.j);
        });
        roots.sort_unstable_by_key(|n| std::cmp::Reverse(n.bound));
        let (leaves, nodes) = roots
            .par_iter()
            .with_max_len(1)
            .fold(
                || (Vec::new(), 0usize, Vec::<Node>::new()),
                |(mut leaves, mut nodes, mut stack), root| {
                    nodes += 1;
                    tree.descend(*root, &mut leaves, &mut nodes, &mut stack);
                    (leaves, nodes, stack)
                },
            )
            .map(|(l, n, _)| (l, n))
            .reduce(
                || (Vec::new(), 0),
                |(mut a, na), (b, nb)| {
                    a.extend(b);
                    (a, na + nb)
                },
            );
        (leaves, nodes, 0)
    }

    /// Heading by heading (in parallel): every free node of level `lvl` in the region
    /// summed densely ([`Self::dense_roots`]), those at the threshold explored depth-first,
    /// best bound first.
    fn start_dense(
        &self,
        tree: &Tree,
        offsets: &[Vec<(i32, i32)>],
        lvl: usize,
    ) -> (Vec<Leaf>, usize, usize) {
        let built;
        let cached = self
            .dense
            .get_or_init(|| DenseLevel::build(&self.field, DENSE_LEVEL.min(self.cfg.levels)));
        let d = if cached.level == lvl {
            cached
        } else {
            // another level (the tests'): built for this search
            built = DenseLevel::build(&self.field, lvl);
            &built
        };
        let rows = self.dense_rows(d, tree.region);
        let (leaves, nodes, summed) = (0..offsets.len())
            .into_par_iter()
            .with_max_len(1)
            .fold(
                || {
                    (
                        Vec::new(),
                        0usize,
                        0usize,
                        Vec::<Node>::new(),
                        Vec::<Node>::new(),
                    )
                },
                |(mut leaves, mut nodes, mut summed, mut roots, mut stack), k| {
                    roots.clear();
                    let job = DenseJob {
                        d,
                        rows: &rows,
                        offs: &offsets[k],
                        k: k as u32,
                        tree,
                    };
                    summed += self.dense_roots(job, &mut roots);
                    roots.sort_unstable_by_key(|n| std::cmp::Reverse(n.bound));
                    nodes += roots.len();
                    for &root in roots.iter() {
                        tree.descend(root, &mut leaves, &mut nodes, &mut stack);
                    }
                    (leaves, nodes, summed, roots, stack)
                },
            )
            .map(|(l, n, s, _, _)| (l, n, s))
            .reduce(
                || (Vec::new(), 0, 0),
                |(mut a, na, sa), (b, nb, sb)| {
                    a.extend(b);
                    (a, na + nb, sa + sb)
                },
            );
        (leaves, nodes, summed)
    }

    /// For each node row b of the dense level (from 0): the columns [a0, a1] from the first
    /// to the last free node in the region (a0 > a1: none).
    fn dense_rows(&self, d: &DenseLevel, region: [i32; 4]) -> Vec<(i32, i32)> {
        let [ri0, rj0, ri1, rj1] = region;
        let s = 1i32 << d.level;
        let free = &self.free[d.level];
        let w = self.field.w;
        let (a_lo, a_hi) = (ri0.div_euclid(s).max(0), ri1.div_euclid(s).min(d.nx - 1));
        let (b_lo, b_hi) = (rj0.div_euclid(s).max(0), rj1.div_euclid(s).min(d.ny - 1));
        (0..d.ny)
            .map(|b| {
                if b < b_lo || b > b_hi {
                    return (1, 0);
                }
                let row = (b * s) as usize * w;
                let is_free = |a: i32| free[row + (a * s) as usize];
                match (a_lo..=a_hi).find(|&a| is_free(a)) {
                    None => (1, 0),
                    Some(a0) => (a0, (a0..=a_hi).rev().find(|&a| is_free(a)).unwrap_or(a0)),
                }
            })
            .collect()
    }

    /// Sum heading `k`'s points (`offs`) over the free nodes of the dense level `d` in the
    /// region's rows `rows`, row by row (each point adds one contiguous run of its residue's
    /// plane), and push those at the threshold as roots. Returns the
    /// number of nodes summed.
    fn dense_roots(&self, job: DenseJob<'_>, roots: &mut Vec<Node>) -> usize {
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            // SAFETY: the CPU has AVX2 (checked at run time)
            return unsafe { self.dense_roots_avx2(job, roots) };
        }
        self.dense_roots_plain(job, roots)
    }

    /// [`Self::dense_roots`] compiled for AVX2 (its row sums: twice the lanes of SSE2's).
    ///
    /// # Safety
    /// The CPU must support AVX2 (`has_avx2()`). An `unsafe fn` rather than a safe
    /// `#[target_feature]` one, which needs Rust 1.86 (the crate's `rust-version` is 1.85).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn dense_roots_avx2(&self, job: DenseJob<'_>, roots: &mut Vec<Node>) -> usize {
        self.dense_roots_plain(job, roots)
    }

    #[inline(always)]
    fn dense_roots_plain(&self, job: DenseJob<'_>, roots: &mut Vec<Node>) -> usize {
        let DenseJob {
            d,
            rows,
            offs,
            k,
            tree,
        } = job;
        let s = 1i32 << d.level;
        // each point: its plane's start and its node shift (qx, qy): the point of node
        // (a, b) reads row b + qy + 1, column a + qx + 1 of its plane
        let pts: Vec<(usize, i32, i32)> = offs
            .iter()
            .map(|&(ox, oy)| {
                let (rx, ry) = (ox.rem_euclid(s), oy.rem_euclid(s));
                (d.plane_of(rx, ry), ox.div_euclid(s), oy.div_euclid(s))
            })
            .collect();
        let thr = tree.threshold();
        let free = &self.free[d.level];
        let w = self.field.w;
        let mut acc: Vec<u16> = Vec::new();
        let mut summed = 0usize;
        for (b, &(a0, a1)) in rows.iter().enumerate() {
            if a0 > a1 {
                continue;
            }
            let b = b as i32;
            acc.clear();
            acc.resize((a1 - a0 + 1) as usize, 0);
            summed += acc.len();
            for &(base, qx, qy) in &pts {
                let r = b + qy;
                if r < -1 || r >= d.ny {
                    continue; // a row wholly outside the grid: 0
                }
                // columns a with a + qx in [-1, nx)
                let lo = a0.max(-1 - qx);
                let hi = (a1 + 1).min(d.nx - qx);
                if lo >= hi {
                    continue;
                }
                let src = &d.cells[base + (r + 1) as usize * d.stride + (lo + qx + 1) as usize..]
                    [..(hi - lo) as usize];
                let dst = &mut acc[(lo - a0) as usize..][..(hi - lo) as usize];
                for (t, &v) in dst.iter_mut().zip(src) {
                    *t += v as u16;
                }
            }
            let row = (b * s) as usize * w;
            for (a, &v) in (a0..=a1).zip(acc.iter()) {
                let bound = v as u32;
                if bound >= thr && free[row + (a * s) as usize] {
                    // (at level 0 a leaf: Tree::descend takes it as one)
                    roots.push(Node {
                        bound,
                        level: d.level as u8,
                        k,
                        i: a * s,
                        j: b * s,
                    });
                }
            }
        }
        summed
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raycast::Segment;
    use crate::testkit::{
        make_scan, office_segments, random_pose, rectangle, sample_segments, Rng,
    };
    use std::time::Instant;

    /// `n` cell offsets drawn uniformly within +-`spread` cells
    fn random_offsets(rng: &mut Rng, n: usize, spread: f64) -> Vec<(i32, i32)> {
        (0..n)
            .map(|_| {
                (
                    rng.range(-spread, spread) as i32,
                    rng.range(-spread, spread) as i32,
                )
            })
            .collect()
    }

    fn localizer(segs: &[Segment], res: f64) -> GlobalLocalizer {
        let (p, n) = sample_segments(segs, 0.05);
        let idx = Arc::new(MapIndex::new(p, Some(n)).unwrap());
        GlobalLocalizer::new(idx, res, GlobalConfig::default()).unwrap()
    }

    fn close(a: Pose2, b: Pose2, d: f64, th: f64) -> bool {
        (a.x - b.x).hypot(a.y - b.y) <= d && wrap_angle(a.theta - b.theta).abs() <= th
    }

    #[test]
    fn office_random_starts() {
        let segs = office_segments();
        let g = localizer(&segs, 0.05);
        let mut rng = Rng::new(11);
        let n = 30;
        let (mut best_ok, mut listed, mut confident_wrong) = (0, 0, 0);
        let t0 = Instant::now();
        for _ in 0..n {
            let truth = random_pose(&mut rng);
            let scan = make_scan(&segs, truth, 361, 30.0, 0.01, 0.05, &mut rng);
            let r = g.search(&scan, None, None).unwrap();
            let b = r.best().unwrap();
            let ok = close(b.pose, truth, 0.05, 1f64.to_radians());
            best_ok += ok as usize;
            for c in &r.candidates {
                let d = g.distance_at([c.pose.x, c.pose.y]).unwrap();
                assert!(d >= 0.1, "candidate in a wall: {c:?}");
            }
            listed += r
                .candidates
                .iter()
                .any(|c| close(c.pose, truth, 0.05, 1f64.to_radians()))
                as usize;
            if !ok && !r.ambiguous {
                confident_wrong += 1;
                eprintln!(
                    "wrong: truth {truth:?} best {b:?} next {:?}",
                    r.candidates.get(1)
                );
            }
            if !ok {
                eprintln!(
                    "miss: truth {truth:?} ambiguous {} leaves {} best {:?} listed at {:?}",
                    r.ambiguous,
                    r.leaves,
                    b,
                    r.candidates
                        .iter()
                        .position(|c| close(c.pose, truth, 0.05, 1f64.to_radians()))
                );
            }
        }
        eprintln!(
            "office: best {best_ok}/{n}, listed {listed}/{n}, confident wrong {confident_wrong}, {:.1} ms/search",
            t0.elapsed().as_secs_f64() * 1e3 / n as f64
        );
        // the office repeats its rooms: one scan is often ambiguous, never confidently wrong
        assert!(best_ok >= n * 8 / 10, "best correct {best_ok}/{n}");
        assert_eq!(listed, n, "truth listed {listed}/{n}");
        assert_eq!(confident_wrong, 0);
    }

    #[test]
    fn symmetric_room_is_ambiguous() {
        // an 8 m x 5 m empty rectangle: (x, y, th) and (8 - x, 5 - y, th + pi) see the same
        let segs = rectangle(8.0, 5.0);
        let g = localizer(&segs, 0.05);
        let mut rng = Rng::new(3);
        let truth = Pose2::new(2.7, 1.8, 0.4);
        let scan = make_scan(&segs, truth, 361, 30.0, 0.005, 0.0, &mut rng);
        let r = g.search(&scan, None, None).unwrap();
        let mirror0 = Pose2::new(
            8.0 - truth.x,
            5.0 - truth.y,
            wrap_angle(truth.theta + std::f64::consts::PI),
        );
        eprintln!(
            "sym: leaves {} nodes {} free {} mirror {:?} truth {:?}",
            r.leaves,
            r.nodes,
            g.free_cells(),
            g.score_pose(&scan, mirror0, 0.0),
            g.score_pose(&scan, truth, 0.0)
        );
        assert!(
            r.ambiguous,
            "{:?}",
            &r.candidates[..2.min(r.candidates.len())]
        );
        let mirror = Pose2::new(
            8.0 - truth.x,
            5.0 - truth.y,
            wrap_angle(truth.theta + std::f64::consts::PI),
        );
        for want in [truth, mirror] {
            assert!(
                r.candidates
                    .iter()
                    .take(4)
                    .any(|c| close(c.pose, want, 0.05, 1f64.to_radians())),
                "{want:?} not among {:?}",
                r.candidates
            );
        }
        // a heading range that excludes the mirror resolves it
        let r = g.search(&scan, None, Some((0.0, 1.0))).unwrap();
        assert!(close(
            r.best().unwrap().pose,
            truth,
            0.05,
            1f64.to_radians()
        ));
        // so does a region around the truth
        let r = g.search(&scan, Some([1.5, 0.5, 4.0, 2.5]), None).unwrap();
        assert!(close(
            r.best().unwrap().pose,
            truth,
            0.05,
            1f64.to_radians()
        ));
        assert!(!r.ambiguous);
    }

    /// The office at 0.1 m and one scan in it from (3, 4, 0): the bad-input and region tests
    fn office_localizer_and_scan() -> (GlobalLocalizer, Vec<[f64; 2]>) {
        let segs = office_segments();
        let g = localizer(&segs, 0.1);
        let mut rng = Rng::new(5);
        let scan = make_scan(
            &segs,
            Pose2::new(3.0, 4.0, 0.0),
            361,
            30.0,
            0.01,
            0.0,
            &mut rng,
        );
        (g, scan)
    }

    #[test]
    fn bad_input_is_an_error() {
        let (g, scan) = office_localizer_and_scan();
        assert!(matches!(
            g.search(&[], None, None),
            Err(IcpError::TooFewPoints { .. })
        ));
        let mut nan = scan.clone();
        nan[4][1] = f64::NAN;
        assert!(matches!(
            g.search(&nan, None, None),
            Err(IcpError::NonFinite { .. })
        ));
        assert!(g
            .search(&scan, Some([100.0, 100.0, 120.0, 120.0]), None)
            .is_err());
        assert!(g.search(&scan, Some([5.0, 0.0, 1.0, 3.0]), None).is_err());
        assert!(g
            .search(&scan, Some([f64::NAN, 0.0, 1.0, 3.0]), None)
            .is_err());
        assert!(g.search(&scan, None, Some((1.0, 0.0))).is_err());
        assert!(g.search(&scan, None, Some((0.0, 10.0))).is_err());
        let idx = g.index().clone();
        for res in [0.0, -1.0, f64::NAN, 1e-5] {
            assert!(GlobalLocalizer::new(idx.clone(), res, GlobalConfig::default()).is_err());
        }
        let cfg = GlobalConfig {
            accept_ratio: 0.0,
            ..GlobalConfig::default()
        };
        assert!(matches!(
            GlobalLocalizer::new(idx.clone(), 0.1, cfg),
            Err(IcpError::InvalidConfig {
                field: "accept_ratio",
                ..
            })
        ));
        // a single-heading search and a region with no free cell are fine
        assert!(g.search(&scan, None, Some((0.5, 0.5))).is_ok());
        let r = g.search(&scan, Some([6.0, 2.0, 6.0, 2.0]), None).unwrap();
        assert!(r.candidates.is_empty());
    }

    #[test]
    fn a_region_narrower_than_a_cell_searches_the_cells_it_overlaps() {
        // a window clipped to a sliver at the map's edge (partial_sim seed 2: 4 cm wide on a
        // coarser grid, between two cell centres) is searched, not refused
        let (g, scan) = office_localizer_and_scan();
        let (x0, y0, res) = (g.field.x0, g.field.y0, g.field.res);
        let (a, b) = (x0 + 20.3 * res, y0 + 20.3 * res);
        for region in [
            [a, y0 + 5.0 * res, a + 0.3 * res, y0 + 30.0 * res],
            [x0 + 5.0 * res, b, x0 + 30.0 * res, b + 0.3 * res],
            [a, b, a + 0.3 * res, b + 0.3 * res],
        ] {
            assert!(g.search(&scan, Some(region), None).is_ok(), "{region:?}");
        }
        // one wider than a cell is searched over the cell centres inside it, as before
        assert!(g
            .search(&scan, Some([a, b, a + 2.0 * res, b + 2.0 * res]), None)
            .is_ok());
    }

    #[test]
    fn refine_and_score() {
        let segs = office_segments();
        let g = localizer(&segs, 0.1);
        let mut rng = Rng::new(8);
        let truth = Pose2::new(3.0, 4.0, 0.3);
        let scan = make_scan(&segs, truth, 361, 30.0, 0.01, 0.0, &mut rng);
        let poses = [Pose2::new(3.2, 3.85, 0.35), Pose2::new(20.0, 15.0, -1.0)];
        let r = g.refine(&scan, &poses).unwrap();
        assert_eq!(r.len(), 2);
        assert!(
            close(r[0].pose, truth, 0.03, 0.5f64.to_radians()),
            "{:?}",
            r[0]
        );
        assert!(r[0].score > 0.8 && r[0].inlier_ratio > 0.95);
        assert!(r[1].score < 0.75 * r[0].score, "{:?}", r[1]);
        let s = g.score(&scan, &[truth, Pose2::new(3.5, 4.0, 0.3)]).unwrap();
        assert!(s[0].score > 0.8 && s[1].score < 0.3, "{s:?}");
        assert!(g.score(&scan, &[Pose2::new(f64::NAN, 0.0, 0.0)]).is_err());
        assert!(g.refine(&scan[..2], &poses).is_err());
    }

    #[test]
    fn see_through_counts_crossings_not_grazing_or_doorways() {
        // a 20 m x 2 m corridor; a cross wall at x = 10 with a 1 m doorway in its middle
        let corridor = rectangle(20.0, 2.0);
        let mut door = corridor.clone();
        door.push([10.0, 0.0, 10.0, 0.5]);
        door.push([10.0, 1.5, 10.0, 2.0]);
        let mut closed = corridor.clone();
        closed.push([10.0, 0.0, 10.0, 2.0]);
        let mut rng = Rng::new(5);
        let pose = Pose2::new(1.0, 1.0, 0.0);
        // beams along the corridor graze its walls for metres, and beams through the
        // doorway pass within centimetres of the jambs: neither is seen through
        for world in [&corridor, &door] {
            let g = localizer(world, 0.05);
            let scan = make_scan(world, pose, 361, 30.0, 0.01, 0.0, &mut rng);
            let st = g.see_through(&scan, pose);
            assert!(st < 0.02, "{st}");
        }
        // the open corridor's scan against a map with the doorway closed: every beam that
        // reaches the far end crossed the wall
        let g = localizer(&closed, 0.05);
        let scan = make_scan(&door, pose, 361, 30.0, 0.01, 0.0, &mut rng);
        let far = scan.iter().filter(|p| p[0] > 9.5).count() as f64 / scan.len() as f64;
        let st = g.see_through(&scan, pose);
        assert!(far > 0.02 && (st - far).abs() < 0.01, "{st} vs {far}");
    }

    #[test]
    fn see_through_counts_shallow_crossings_on_a_dense_map() {
        // a wall along y = 5 sampled every 1 cm (5x finer than the 5 cm grid)
        let wall: Vec<Segment> = vec![[-30.0, 5.0, 30.0, 5.0]];
        let (p, n) = sample_segments(&wall, 0.01);
        let idx = Arc::new(MapIndex::new(p, Some(n)).unwrap());
        let g = GlobalLocalizer::new(idx, 0.05, GlobalConfig::default()).unwrap();
        for deg in [20.0f64, 30.0, 45.0, 70.0, 90.0] {
            let a = deg.to_radians();
            // 50 beams from origins at different distances below the wall: every phase of
            // the 5 cm ray steps against the crossing and the 1 cm samples
            let crossed = (0..50)
                .filter(|k| {
                    let y0 = 0.0013 * *k as f64;
                    let r = (5.0 - y0) / a.sin() + 3.0; // the return is 3 m beyond the wall
                    let beam = [[r * a.cos(), r * a.sin()]];
                    g.see_through(&beam, Pose2::new(0.007 * *k as f64, y0, 0.0)) > 0.5
                })
                .count();
            assert_eq!(crossed, 50, "{deg} deg: {crossed} of 50 crossings seen");
        }
    }

    /// Every leaf of the exhaustive search within `accept_ratio` of the best: the
    /// branch-and-bound must return exactly these.
    fn exhaustive_leaves(
        g: &GlobalLocalizer,
        offsets: &[Vec<(i32, i32)>],
        region: [i32; 4],
        m: usize,
    ) -> Vec<(u32, u32, i32, i32)> {
        let [ri0, rj0, ri1, rj1] = region;
        let mut all = Vec::new();
        for (k, offs) in offsets.iter().enumerate() {
            for j in rj0..=rj1 {
                for i in ri0..=ri1 {
                    if g.free[0][j as usize * g.field.w + i as usize] {
                        all.push((g.field.sum(0, offs, i, j), k as u32, i, j));
                    }
                }
            }
        }
        let floor = (g.cfg.min_score * (255 * m) as f64).ceil() as u32;
        let best = all.iter().map(|l| l.0).max().unwrap_or(0).max(floor);
        let keep = ((best as f64) * g.cfg.accept_ratio)
            .ceil()
            .max(floor as f64) as u32;
        let mut kept: Vec<_> = all.into_iter().filter(|l| l.0 >= keep).collect();
        kept.sort_unstable();
        kept
    }

    /// The search from the dense level finds exactly the leaves of the search from the
    /// top level's nodes (the tree before the dense level): every heading, floor and
    /// region, on maps whose scans reach past the grid's edges, and for pyramids lower
    /// than the dense level (down to none at all); below the dense level it scores the
    /// same nodes when the floor decides (the best leaf's share does not move the bar).
    #[test]
    fn the_dense_start_keeps_exactly_the_leaves_of_the_top_start() {
        let segs = office_segments();
        let mut rng = Rng::new(29);
        let mut compared = 0;
        for (res, levels) in [(0.05, 6), (0.1, 6), (0.1, 2), (0.2, 0)] {
            let (p, n) = sample_segments(&segs, 0.05);
            let idx = Arc::new(MapIndex::new(p, Some(n)).unwrap());
            let cfg = GlobalConfig {
                levels,
                ..GlobalConfig::default()
            };
            let g = GlobalLocalizer::new(idx, res, cfg).unwrap();
            let (w, h) = (g.field.w as i32, g.field.h as i32);
            for t in 0..6 {
                let truth = random_pose(&mut rng);
                let scan = make_scan(&segs, truth, 361, 30.0, 0.01, 0.05, &mut rng);
                let m = scan.len().min(g.cfg.max_points);
                let sub: Vec<[f64; 2]> = (0..m).map(|k| scan[k * scan.len() / m]).collect();
                let headings: Vec<f64> = if t % 2 == 0 {
                    (0..180).map(|k| k as f64 * 2f64.to_radians()).collect()
                } else {
                    (0..25)
                        .map(|k| truth.theta - 0.4 + k as f64 * 0.033)
                        .collect()
                };
                let offsets = cell_offsets(&sub, headings.into_iter(), g.field.res);
                let region = match t / 2 {
                    0 => [0, 0, w - 1, h - 1],
                    1 => [w / 5, 3, w - 2, h / 2 + 7],
                    _ => [0, h / 3, w / 3 + 1, h - 1],
                };
                for floor in [g.cfg.min_score, 0.4, 0.6, 0.9] {
                    let lvl = DENSE_LEVEL.min(levels);
                    let top = g.coarse_from(&offsets, region, m, floor, None);
                    let dense = g.coarse_from(&offsets, region, m, floor, Some(lvl));
                    let key = |c: &Coarse| {
                        let mut v: Vec<_> =
                            c.leaves.iter().map(|l| (l.score, l.k, l.i, l.j)).collect();
                        v.sort_unstable();
                        v
                    };
                    let want = key(&top);
                    assert_eq!(
                        key(&dense),
                        want,
                        "res {res} levels {levels} case {t} floor {floor}"
                    );
                    assert!(dense.dense > 0 && top.dense == 0);
                    compared += want.len();
                    if floor >= 0.6 && levels == 6 && !want.is_empty() {
                        // the floor is the bar (the best leaf is below floor / accept_ratio)
                        let best = want.iter().map(|l| l.0).max().unwrap() as f64;
                        if best * g.cfg.accept_ratio < (floor * (255 * m) as f64).ceil() {
                            assert!(dense.nodes < top.nodes, "{} vs {}", dense.nodes, top.nodes);
                        }
                    }
                }
            }
        }
        assert!(compared > 500, "{compared} leaves compared");
    }

    #[test]
    fn child_sums_are_the_field_sums_also_at_the_edges() {
        let g = localizer(&office_segments(), 0.1);
        let f = &g.field;
        let (w, h) = (f.w as i32, f.h as i32);
        let mut rng = Rng::new(3);
        let offs: Vec<(i32, i32)> = (0..60)
            .map(|_| (rng.range(-80.0, 80.0) as i32, rng.range(-80.0, 80.0) as i32))
            .collect();
        for level in 0..f.levels() {
            let s = 1i32 << level;
            for (i, j) in [
                (0, 0),
                (-s, -s),
                (w - 1, h - 1),
                (w - s, 3),
                (17, h - s),
                (40, 30),
            ] {
                let want = [
                    f.sum(level, &offs, i, j),
                    f.sum(level, &offs, i + s, j),
                    f.sum(level, &offs, i, j + s),
                    f.sum(level, &offs, i + s, j + s),
                ];
                assert_eq!(
                    child_sums(f, level, &offs, i, j),
                    want,
                    "level {level} at ({i}, {j})"
                );
            }
        }
    }

    #[test]
    fn shifted_child_sums_are_the_child_sums_inside_and_at_the_edges() {
        let g = localizer(&office_segments(), 0.05);
        let f = &g.field;
        let (w, h) = (f.w as i32, f.h as i32);
        let mut rng = Rng::new(11);
        for spread in [3.0, 20.0, 80.0] {
            let offs = random_offsets(&mut rng, 50, spread);
            let sh = Shifts::new(&offs, f.w);
            for level in 0..f.levels() {
                let s = 1i32 << level;
                let mut at = vec![(0, 0), (-s, -s), (w - 1, h - 1), (w - s, 3), (17, h - s)];
                at.extend((0..300).map(|_| {
                    (
                        rng.range(-10.0, w as f64 + 10.0) as i32,
                        rng.range(-10.0, h as f64 + 10.0) as i32,
                    )
                }));
                for (i, j) in at {
                    assert_eq!(
                        child_sums_shifted(f, level, &sh, i, j),
                        child_sums(f, level, &offs, i, j),
                        "spread {spread} level {level} at ({i}, {j})"
                    );
                }
            }
        }
        // a heading with no points sums to nothing
        let none = Shifts::new(&[], f.w);
        assert_eq!(child_sums_shifted(f, 2, &none, 5, 5), [0; 4]);
    }

    #[test]
    fn child_sums_above_drop_a_node_exactly_when_every_child_is_below_the_threshold() {
        let g = localizer(&office_segments(), 0.05);
        let f = &g.field;
        let (w, h) = (f.w as i32, f.h as i32);
        let mut rng = Rng::new(13);
        let (mut dropped, mut kept) = (0usize, 0usize);
        for (n, spread) in [(96, 5.0), (96, 40.0), (40, 15.0), (7, 3.0)] {
            let offs = random_offsets(&mut rng, n, spread);
            let sh = Shifts::new(&offs, f.w);
            for level in 0..f.levels() {
                for _ in 0..200 {
                    let (i, j) = (
                        rng.range(-10.0, w as f64 + 10.0) as i32,
                        rng.range(-10.0, h as f64 + 10.0) as i32,
                    );
                    // the node's bound as the search has it: its level's sum
                    let bound = f.sum(level + 1, &offs, i, j);
                    let want = child_sums(f, level, &offs, i, j);
                    let top = *want.iter().max().unwrap();
                    for thr in [0, top / 2, top, top + 1, top + 255, bound, bound + 1] {
                        let got = child_sums_above(f, level, &sh, i, j, bound, thr);
                        if top >= thr {
                            assert_eq!(got, Some(want), "level {level} at ({i}, {j}) thr {thr}");
                            kept += 1;
                        } else {
                            assert_eq!(got, None, "level {level} at ({i}, {j}) thr {thr}");
                            dropped += 1;
                        }
                    }
                    // a looser bound may keep a node whose children all fall short, never
                    // change the sums
                    let got = child_sums_above(f, level, &sh, i, j, bound.saturating_mul(2), top);
                    assert_eq!(got, Some(want));
                }
            }
        }
        assert!(
            dropped > 1000 && kept > 1000,
            "dropped {dropped}, kept {kept}"
        );
    }

    #[test]
    fn branch_and_bound_keeps_exactly_the_exhaustive_leaves() {
        let segs = office_segments();
        let g = localizer(&segs, 0.1);
        let mut rng = Rng::new(5);
        let (w, h) = (g.field.w as i32, g.field.h as i32);
        for (t, region) in [[0, 0, w - 1, h - 1], [37, 11, 151, 90], [0, 5, 64, 69]]
            .into_iter()
            .enumerate()
        {
            let truth = random_pose(&mut rng);
            let scan = make_scan(&segs, truth, 181, 30.0, 0.01, 0.05, &mut rng);
            let m = scan.len().min(g.cfg.max_points);
            let sub: Vec<[f64; 2]> = (0..m).map(|k| scan[k * scan.len() / m]).collect();
            let offsets = cell_offsets(
                &sub,
                (0..(36 + 12 * t)).map(|k| k as f64 * 0.17),
                g.field.res,
            );
            let region = [
                region[0],
                region[1],
                region[2].min(w - 1),
                region[3].min(h - 1),
            ];
            let (leaves, nodes) = g.coarse_leaves(&offsets, region, m, g.cfg.min_score);
            let mut got: Vec<_> = leaves.iter().map(|l| (l.score, l.k, l.i, l.j)).collect();
            got.sort_unstable();
            let want = exhaustive_leaves(&g, &offsets, region, m);
            assert!(!want.is_empty());
            assert_eq!(got, want, "region {region:?}: {nodes} nodes");
        }
    }

    /// The office map's localizer at 5 cm and a 361-beam scan at (21, 9.5, 1.0) of it
    /// (1 cm range noise, 5 % clutter) drawn with `seed`.
    fn office_case(seed: u64) -> (GlobalLocalizer, Vec<[f64; 2]>) {
        let segs = office_segments();
        let g = localizer(&segs, 0.05);
        let mut rng = Rng::new(seed);
        let scan = make_scan(
            &segs,
            Pose2::new(21.0, 9.5, 1.0),
            361,
            30.0,
            0.01,
            0.05,
            &mut rng,
        );
        (g, scan)
    }

    #[test]
    fn search_is_deterministic() {
        let (g, scan) = office_case(17);
        let a = g.search(&scan, None, None).unwrap();
        for _ in 0..3 {
            let b = g.search(&scan, None, None).unwrap();
            assert_eq!(a.candidates, b.candidates);
            assert_eq!((a.ambiguous, a.leaves), (b.ambiguous, b.leaves));
        }
    }

    #[test]
    fn search_above_prunes_below_its_floor_only() {
        let (g, scan) = office_case(23);
        let a = g.search(&scan, None, None).unwrap();
        let top = a
            .candidates
            .iter()
            .map(|c| c.coarse_score)
            .fold(0.0f64, f64::max);
        assert!(top > 0.5, "{top}");
        // a floor the accept ratio already implies: the same result
        let b = g.search_above(&scan, None, None, Some(0.75 * top)).unwrap();
        assert_eq!(a.candidates, b.candidates);
        assert_eq!(a.leaves, b.leaves);
        // a floor above every pose: nothing, almost at once
        let c = g.search_above(&scan, None, None, Some(0.99)).unwrap();
        assert!(c.candidates.is_empty());
        assert!(c.nodes * 4 < a.nodes, "{} vs {}", c.nodes, a.nodes);
        for bad in [-0.1, 1.0, f64::NAN] {
            assert!(g.search_above(&scan, None, None, Some(bad)).is_err());
        }
    }

    /// A 40 m x 20 m building of identical rooms along two corridors (timing, printed).
    #[test]
    fn building_timing() {
        let mut segs: Vec<Segment> = vec![
            [0.0, 0.0, 40.0, 0.0],
            [40.0, 0.0, 40.0, 20.0],
            [40.0, 20.0, 0.0, 20.0],
            [0.0, 20.0, 0.0, 0.0],
        ];
        for &y in &[7.0, 9.0, 11.0, 13.0] {
            let mut x = 0.0;
            while x < 40.0 {
                segs.push([x, y, x + 3.0, y]);
                x += 4.0;
            }
        }
        let mut x = 4.0;
        while x < 40.0 {
            segs.push([x, 0.0, x, 7.0]);
            segs.push([x, 13.0, x, 20.0]);
            x += 4.0;
        }
        let t = Instant::now();
        let g = localizer(&segs, 0.05);
        let build = t.elapsed().as_secs_f64() * 1e3;
        let mut rng = Rng::new(9);
        let truth = Pose2::new(21.3, 10.2, 0.7);
        let scan = make_scan(&segs, truth, 361, 30.0, 0.01, 0.05, &mut rng);
        let _ = g.search(&scan, None, None).unwrap();
        let t = Instant::now();
        let reps = 3;
        let mut r = None;
        for _ in 0..reps {
            r = Some(g.search(&scan, None, None).unwrap());
        }
        let r = r.unwrap();
        eprintln!(
            "building {:?}: build {build:.0} ms, search {:.1} ms (coarse {:.1}, refine {:.1}), nodes {}, leaves {}, candidates {}, ambiguous {}",
            g.shape(),
            t.elapsed().as_secs_f64() * 1e3 / reps as f64,
            r.coarse_time * 1e3,
            r.refine_time * 1e3,
            r.nodes,
            r.leaves,
            r.candidates.len(),
            r.ambiguous
        );
        assert!(r
            .candidates
            .iter()
            .any(|c| close(c.pose, truth, 0.05, 1f64.to_radians())));
    }
}
