//! The ICP loop (Besl & McKay, as the paper uses it), with the point-to-line alternative.
//!
//! One iteration: transform the scan by the current pose, find the closest map point of
//! every scan point (k-d tree), drop pairs farther apart than the current threshold (the
//! paper's occlusion filter; the threshold may shrink from iteration to iteration), keep
//! the best fraction (trimmed ICP), weight (Huber/Cauchy), and solve: point-to-point by the
//! quaternion registration of the scan (P₀) onto its matches (Y_k), or point-to-line by one
//! Gauss–Newton step on (x, y, θ) using the map normals. Stop when the mean-square error
//! falls below τ, its relative change below ε, the step below a tolerance (once the
//! threshold has reached its final value), or at the iteration limit (not converged).

use nalgebra::{Matrix2, Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use crate::error::{IcpError, Result};
use crate::index::MapIndex;
use crate::quaternion::CrossCovariance;
use crate::se2::{wrap_angle, Pose2};

mod local;
mod window;
pub(crate) use local::map_directions;
use window::assess_with;
pub use window::{assess, see_through, Fit};

/// The error metric.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    /// The paper's metric: squared distance between a scan point and its closest map point.
    PointToPoint,
    /// Squared distance from a scan point to the line through its closest map point along
    /// that point's normal.
    PointToLine,
}

/// Robust weights applied on top of the distance threshold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Robust {
    None,
    Huber,
    Cauchy,
}

/// ICP settings. Distances in metres, MSE in m².
#[derive(Clone, Debug, PartialEq)]
pub struct IcpConfig {
    pub metric: Metric,
    pub max_iterations: usize,
    /// Correspondence threshold of the first iteration.
    pub max_correspondence_distance: f64,
    /// Final (smallest) correspondence threshold.
    pub min_correspondence_distance: f64,
    /// Per-iteration factor of the shrinking threshold, in (0, 1]; 1 keeps it fixed at
    /// `max_correspondence_distance`.
    pub threshold_decay: f64,
    /// Fraction of the thresholded pairs kept (best first), in (0, 1].
    pub trim_fraction: f64,
    pub robust: Robust,
    /// Scale k of the Huber/Cauchy weight (m).
    pub robust_scale: f64,
    /// τ: stop when the MSE falls below it (the paper's rule).
    pub mse_threshold: f64,
    /// ε: stop when the relative change of the MSE falls below it.
    pub mse_change: f64,
    /// Stop when the pose update is smaller than this (m, and rad × 1 m); point-to-line
    /// (Gauss–Newton, about quadratic once the pairs hold) stops at a step below its square
    /// root (at most 1 mm / 1 mrad): the next step would be about this small.
    pub step_tolerance: f64,
    /// Fewer inliers than this: stop, not converged.
    pub min_inliers: usize,
    /// A lower inlier ratio than this: stop, not converged.
    pub min_inlier_ratio: f64,
    /// Half-range (rad) of a search over initial headings before the ICP proper, for
    /// large start errors; 0 turns it off. Each heading θ₀ + k·`heading_step` within the
    /// range gets a short coarse ICP on a subsample, and the ICP starts from the one with
    /// the most pairs closer than `min_correspondence_distance`.
    pub heading_search: f64,
    /// Step of the heading search (rad).
    pub heading_step: f64,
    /// Also try start positions offset by ±this (m) in x and y — a 3 × 3 grid around the
    /// start, with every searched heading — unless a heading at the start position already
    /// explains most of the scan; 0 turns it off.
    pub position_search: f64,
    /// The verified start: when the ICP result does not explain the scan (see
    /// `accept_inlier_ratio`, `accept_see_through`, `expected_noise`; a fit with a tight RMS
    /// explains it with fewer inliers, see `acceptable`) or lies outside the window, search
    /// the window around the initial pose (branch and bound on the map's likelihood
    /// pyramid; first at a few headings around the heading prior, see `local`) and refine
    /// the best poses found there by ICP (and a wider second pass when none of them is free
    /// of beams through walls). A fit in a corridor (translational degeneracy below 0.25)
    /// is compared with the other places along the corridor first. `false` turns it off.
    pub window_search: bool,
    /// Half-width of the window in x and in y (m).
    pub window_position: f64,
    /// Half-width of the window in heading (rad).
    pub window_heading: f64,
    /// Heading step of the window search (rad).
    pub window_angle_step: f64,
    /// σ of the range noise (and map error) expected of a right fit (m): points within
    /// 3σ of the map are inliers, and their RMS must stay below 2σ.
    pub expected_noise: f64,
    /// A fit with a lower share of inliers than this does not explain the scan.
    pub accept_inlier_ratio: f64,
    /// A fit with a higher share of beams passing through mapped walls than this does not
    /// explain the scan.
    pub accept_see_through: f64,
    /// A fit from the heading prior that explains the scan only by the looser rules (a
    /// tight or occluded fit) and whose inliers' RMS is at most this many `expected_noise`
    /// is taken without comparing it with the ICP from the initial pose; 0 always compares
    /// (one more ICP on such starts). On the tuned families' small starts the turned fits
    /// that the comparison corrected had an RMS of 0.58-0.74 σ, the right ones 0.35-0.47 σ.
    pub prior_sure_rms: f64,
    /// Beams that cross only mapped objects of at most this size (bounding-box diagonal,
    /// m) that the scan does not see at all (a parked car that has left since mapping)
    /// do not count against a tight fit as beams through walls ([`Fit::vanished`]);
    /// 0 counts every crossing (off). Free-standing partitions and wall stubs of about
    /// this size are "objects" too.
    pub vanished_object_size: f64,
}

/// The iteration limit may not exceed this (a larger one is a typo, and could hang a call).
pub const MAX_ITERATIONS: usize = 100_000;
/// Start candidates (headings × positions) the heading/position search may try at most.
pub const MAX_START_CANDIDATES: usize = 10_000;
/// Poses (headings × cells) the window search may cover at most.
pub const MAX_WINDOW_POSES: f64 = 5e7;

impl Default for IcpConfig {
    fn default() -> Self {
        Self {
            metric: Metric::PointToLine,
            max_iterations: 50,
            max_correspondence_distance: 1.0,
            min_correspondence_distance: 0.1,
            threshold_decay: 0.6,
            trim_fraction: 1.0,
            robust: Robust::Huber,
            robust_scale: 0.05,
            mse_threshold: 1e-8,
            mse_change: 1e-6,
            step_tolerance: 1e-5,
            min_inliers: 10,
            min_inlier_ratio: 0.0,
            heading_search: 0.0,
            heading_step: 5f64.to_radians(),
            position_search: 0.0,
            window_search: true,
            window_position: 1.0,
            window_heading: 30f64.to_radians(),
            window_angle_step: 2f64.to_radians(),
            expected_noise: 0.02,
            accept_inlier_ratio: 0.75,
            accept_see_through: 0.05,
            prior_sure_rms: 0.5,
            vanished_object_size: 6.0,
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

impl IcpConfig {
    /// The paper's setting: point-to-point, one fixed threshold.
    pub fn paper(threshold: f64) -> Self {
        Self {
            metric: Metric::PointToPoint,
            max_correspondence_distance: threshold,
            min_correspondence_distance: threshold,
            threshold_decay: 1.0,
            ..Self::default()
        }
    }

    /// Check every value; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let pos = |v: f64| v > 0.0 && v.is_finite();
        let nonneg = |v: f64| v >= 0.0 && v.is_finite();
        if self.max_iterations == 0 {
            return Err(bad("max_iterations", 0, "must be at least 1"));
        }
        if self.max_iterations > MAX_ITERATIONS {
            return Err(bad(
                "max_iterations",
                self.max_iterations,
                "must be at most 100,000",
            ));
        }
        if !pos(self.max_correspondence_distance) {
            return Err(bad(
                "max_correspondence_distance",
                self.max_correspondence_distance,
                "must be positive and finite",
            ));
        }
        if !pos(self.min_correspondence_distance) {
            return Err(bad(
                "min_correspondence_distance",
                self.min_correspondence_distance,
                "must be positive and finite",
            ));
        }
        if self.min_correspondence_distance > self.max_correspondence_distance {
            return Err(bad(
                "min_correspondence_distance",
                self.min_correspondence_distance,
                "must not exceed max_correspondence_distance",
            ));
        }
        if !(self.threshold_decay > 0.0 && self.threshold_decay <= 1.0) {
            return Err(bad(
                "threshold_decay",
                self.threshold_decay,
                "must be in (0, 1]",
            ));
        }
        if !(self.trim_fraction > 0.0 && self.trim_fraction <= 1.0) {
            return Err(bad(
                "trim_fraction",
                self.trim_fraction,
                "must be in (0, 1]",
            ));
        }
        if !pos(self.robust_scale) {
            return Err(bad(
                "robust_scale",
                self.robust_scale,
                "must be positive and finite",
            ));
        }
        if !nonneg(self.mse_threshold) {
            return Err(bad(
                "mse_threshold",
                self.mse_threshold,
                "must be non-negative and finite",
            ));
        }
        if !nonneg(self.mse_change) {
            return Err(bad(
                "mse_change",
                self.mse_change,
                "must be non-negative and finite",
            ));
        }
        if !nonneg(self.step_tolerance) {
            return Err(bad(
                "step_tolerance",
                self.step_tolerance,
                "must be non-negative and finite",
            ));
        }
        if self.min_inliers < 3 {
            return Err(bad(
                "min_inliers",
                self.min_inliers,
                "must be at least 3 (a planar pose has three unknowns)",
            ));
        }
        if !(self.heading_search >= 0.0 && self.heading_search <= std::f64::consts::PI) {
            return Err(bad(
                "heading_search",
                self.heading_search,
                "must be in [0, pi]",
            ));
        }
        if !(self.heading_step > 0.0 && self.heading_step.is_finite()) {
            return Err(bad(
                "heading_step",
                self.heading_step,
                "must be positive and finite",
            ));
        }
        if !(self.position_search >= 0.0 && self.position_search.is_finite()) {
            return Err(bad(
                "position_search",
                self.position_search,
                "must be non-negative and finite",
            ));
        }
        if !(0.0..=1.0).contains(&self.min_inlier_ratio) {
            return Err(bad(
                "min_inlier_ratio",
                self.min_inlier_ratio,
                "must be in [0, 1]",
            ));
        }
        let headings = 2.0 * (self.heading_search / self.heading_step).round() + 1.0;
        let positions = if self.position_search > 0.0 { 9.0 } else { 1.0 };
        if headings * positions > MAX_START_CANDIDATES as f64 {
            return Err(bad(
                "heading_step",
                self.heading_step,
                "heading_search / heading_step gives more start candidates (headings x positions) than 10,000",
            ));
        }
        if !(self.window_position >= 0.0 && self.window_position <= 100.0) {
            return Err(bad(
                "window_position",
                self.window_position,
                "must be in [0, 100] m",
            ));
        }
        if !(self.window_heading >= 0.0 && self.window_heading <= std::f64::consts::PI) {
            return Err(bad(
                "window_heading",
                self.window_heading,
                "must be in [0, pi]",
            ));
        }
        if !(self.window_angle_step > 0.0 && self.window_angle_step.is_finite()) {
            return Err(bad(
                "window_angle_step",
                self.window_angle_step,
                "must be positive and finite",
            ));
        }
        let cells =
            2.0 * (self.window_position / crate::likelihood::WINDOW_RESOLUTION).round() + 1.0;
        let wh = 2.0 * (self.window_heading / self.window_angle_step).round() + 1.0;
        if wh * cells * cells > MAX_WINDOW_POSES {
            return Err(bad(
                "window_angle_step",
                self.window_angle_step,
                "the window (window_position, window_heading / window_angle_step) holds more than 5e7 poses",
            ));
        }
        if !pos(self.expected_noise) {
            return Err(bad(
                "expected_noise",
                self.expected_noise,
                "must be positive and finite",
            ));
        }
        if !(0.0..=1.0).contains(&self.accept_inlier_ratio) {
            return Err(bad(
                "accept_inlier_ratio",
                self.accept_inlier_ratio,
                "must be in [0, 1]",
            ));
        }
        if !(0.0..=1.0).contains(&self.accept_see_through) {
            return Err(bad(
                "accept_see_through",
                self.accept_see_through,
                "must be in [0, 1]",
            ));
        }
        if !nonneg(self.prior_sure_rms) {
            return Err(bad(
                "prior_sure_rms",
                self.prior_sure_rms,
                "must be non-negative and finite",
            ));
        }
        if !nonneg(self.vanished_object_size) {
            return Err(bad(
                "vanished_object_size",
                self.vanished_object_size,
                "must be non-negative and finite",
            ));
        }
        Ok(())
    }

    /// The correspondence threshold at iteration `k` (0-based).
    #[inline]
    pub fn threshold_at(&self, k: usize) -> f64 {
        let t = self.max_correspondence_distance * self.threshold_decay.powi(k as i32);
        t.max(self.min_correspondence_distance)
    }

    #[inline]
    fn final_threshold(&self) -> f64 {
        if self.threshold_decay >= 1.0 {
            self.max_correspondence_distance
        } else {
            self.min_correspondence_distance
        }
    }
}

/// Why the loop stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    MseBelowThreshold,
    MseChangeBelowEpsilon,
    StepBelowTolerance,
    MaxIterations,
    TooFewInliers,
}

impl Termination {
    pub fn as_str(&self) -> &'static str {
        match self {
            Termination::MseBelowThreshold => "mse_below_threshold",
            Termination::MseChangeBelowEpsilon => "mse_change_below_epsilon",
            Termination::StepBelowTolerance => "step_below_tolerance",
            Termination::MaxIterations => "max_iterations",
            Termination::TooFewInliers => "too_few_inliers",
        }
    }

    pub fn converged(&self) -> bool {
        matches!(
            self,
            Termination::MseBelowThreshold
                | Termination::MseChangeBelowEpsilon
                | Termination::StepBelowTolerance
        )
    }
}

/// Which start the result came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StartPath {
    /// The ICP from the initial pose explained the scan: no search.
    Plain,
    /// The heading prior (the heading at which the scan's wall directions line up with the
    /// map's) disagreed with the initial heading by more than a few degrees, and the ICP
    /// from the initial position at the prior's heading explained the scan.
    Prior,
    /// It lay in a corridor (or did not explain the scan, and nothing the window search
    /// found explained it better): the result is the ICP from another place along the
    /// corridor.
    Local,
    /// It did not; the window search ran and its refinement did not beat the plain fit.
    WindowKeptPlain,
    /// It did not; the result is the ICP refinement of a window-search pose.
    Window,
}

impl StartPath {
    pub fn as_str(&self) -> &'static str {
        match self {
            StartPath::Plain => "plain",
            StartPath::Prior => "prior",
            StartPath::Local => "local",
            StartPath::WindowKeptPlain => "window_kept_plain",
            StartPath::Window => "window",
        }
    }
}

/// What one alignment did.
#[derive(Clone, Debug, PartialEq)]
pub struct IcpResult {
    /// Sensor pose in the map frame.
    pub pose: Pose2,
    pub converged: bool,
    pub iterations: usize,
    /// Mean-square error of the last iteration's inliers (m²), in the chosen metric.
    pub mse: f64,
    pub inliers: usize,
    pub num_points: usize,
    /// 3×3 covariance of (x, y, θ): σ² H⁻¹ of the point-to-line cost at the final pose.
    pub covariance: [[f64; 3]; 3],
    /// 3×3 information (Hessian, Jᵀ J) of the point-to-line cost at the final pose.
    pub information: [[f64; 3]; 3],
    /// λ_min / λ_max of the translational information, in [0, 1] (0: a corridor).
    pub degeneracy: f64,
    /// Unit vector (map frame) of the least constrained translation.
    pub degenerate_direction: [f64; 2],
    pub termination: Termination,
    /// Which start the result came from.
    pub start: StartPath,
    /// How well the final pose explains the scan (`None` with `window_search` off).
    pub fit: Option<Fit>,
    /// Coarse (pyramid) score in [0, 1] of the window's best pose, and of the best pose
    /// distinct from it (≥ 0.3 m or ≈ 6° away; 0 when none scored 80 % of the best):
    /// `None` when the window search did not run.
    pub window_score: Option<f64>,
    pub window_second: Option<f64>,
}

impl IcpResult {
    pub fn inlier_ratio(&self) -> f64 {
        if self.num_points == 0 {
            0.0
        } else {
            self.inliers as f64 / self.num_points as f64
        }
    }
}

#[derive(Clone, Copy)]
struct Pair {
    /// scan point index
    i: u32,
    /// map point index
    j: u32,
    /// squared point-to-point distance
    d2: f64,
}

/// Reusable buffers for one alignment.
#[derive(Default)]
struct Workspace {
    pairs: Vec<Pair>,
    moved: Vec<[f64; 2]>,
    /// indices of the coarse stages' subsample of the scan
    coarse: Vec<u32>,
    /// the closest map point of every scan point in the last ICP call's last pass over the
    /// whole scan, and the pose of that pass (`None`: its last pass saw a subsample);
    /// [`UNKNOWN`] for a point with no map point within the grid's reach (its exact answer
    /// is asked only when needed, [`Workspace::resolve_nn`])
    nn: Vec<u32>,
    nn_pose: Option<Pose2>,
    /// the scan's farthest range (m), for the shift of a step at its far end
    reach: f64,
    /// [`gather`]'s queries and their answers
    queries: Vec<[f64; 2]>,
    answers: Vec<(f64, u32)>,
}

/// See [`Workspace::nn`].
const UNKNOWN: u32 = window::FAR;

impl Workspace {
    /// The exact answers (the index's own) for the points of the last pass whose closest
    /// map point [`gather`] left [`UNKNOWN`], at that pass's moved points.
    fn resolve_nn(&mut self, index: &MapIndex) {
        for (j, q) in self.nn.iter_mut().zip(&self.moved) {
            if *j == UNKNOWN {
                *j = index.correspondence(*q).1 as u32;
            }
        }
    }
}

/// The fit of `r`, the result of the last [`align_plain`] call with `ws` on `scan`: from
/// that call's closest points when its last pass over the whole scan was within
/// [`window::REUSE_SHIFT`] of the final pose at every point (a converged ICP: its last
/// step was below a millimetre), else by a fresh [`assess`].
fn assessed(
    scan: &[[f64; 2]],
    index: &MapIndex,
    r: &IcpResult,
    cfg: &IcpConfig,
    ws: &mut Workspace,
) -> Fit {
    if let Some(p) = ws.nn_pose {
        let shift = (r.pose.x - p.x).hypot(r.pose.y - p.y)
            + wrap_angle(r.pose.theta - p.theta).abs() * ws.reach;
        if shift <= window::REUSE_SHIFT && ws.nn.len() == scan.len() {
            // the points with no map point within the grid's reach need their exact
            // answer (a k-d tree search each, far from the map) only when they could
            // count in the fit
            let near = 2.0 * index.spacing() + 3.0 * cfg.expected_noise;
            if !window::far_is_nothing(cfg, near) {
                ws.resolve_nn(index);
            }
            return assess_with(scan, index, r.pose, cfg, &ws.nn);
        }
    }
    assess(scan, index, r.pose, cfg)
}

/// Validate the scan and the pose.
fn check_inputs(scan: &[[f64; 2]], initial: Pose2, cfg: &IcpConfig) -> Result<()> {
    cfg.validate()?;
    let min = cfg.min_inliers.max(3);
    if scan.len() < min {
        return Err(IcpError::TooFewPoints {
            what: "scan".into(),
            got: scan.len(),
            min,
        });
    }
    crate::check_finite("scan", scan)?;
    if !initial.is_finite() {
        return Err(IcpError::InvalidInput {
            what: "initial_pose".into(),
            reason: format!(
                "must be finite, got ({}, {}, {})",
                initial.x, initial.y, initial.theta
            ),
        });
    }
    Ok(())
}

#[inline]
fn robust_weight(kind: Robust, k: f64, r: f64) -> f64 {
    match kind {
        Robust::None => 1.0,
        Robust::Huber => {
            let a = r.abs();
            if a <= k {
                1.0
            } else {
                k / a
            }
        }
        Robust::Cauchy => 1.0 / (1.0 + (r / k) * (r / k)),
    }
}

/// Align `scan` (sensor frame) to the map from `initial` (sensor pose in the map).
pub fn align(
    scan: &[[f64; 2]],
    index: &MapIndex,
    initial: Pose2,
    cfg: &IcpConfig,
) -> Result<IcpResult> {
    check_inputs(scan, initial, cfg)?;
    // the thread's buffers of its last call (no allocation per call); a fresh set in the
    // (impossible) case of a call from inside a call
    WORKSPACE.with(|w| match w.try_borrow_mut() {
        Ok(mut ws) => {
            let r = align_unchecked(scan, index, initial, cfg, &mut ws);
            // a huge scan's buffers are not kept for the thread's life
            if ws.moved.capacity() > KEPT_WORKSPACE_POINTS {
                *ws = Workspace::default();
            }
            Ok(r)
        }
        Err(_) => Ok(align_unchecked(
            scan,
            index,
            initial,
            cfg,
            &mut Workspace::default(),
        )),
    })
}

/// [`align`] keeps its buffers between calls for scans of up to this many points.
const KEPT_WORKSPACE_POINTS: usize = 1 << 16;

thread_local! {
    /// [`align`]'s buffers, kept between calls on a thread: every call sizes and fills
    /// them before it reads them (and resets the last pass's pose), so a call's result does
    /// not depend on the calls before it.
    static WORKSPACE: std::cell::RefCell<Workspace> = std::cell::RefCell::new(Workspace::default());
}

/// `align_batch` uses at most this many threads per core (a larger request is clamped).
pub const MAX_THREADS_PER_CORE: usize = 4;

/// Align many (scan, initial pose) pairs in parallel (rayon). `scans` has one entry per
/// pose, or a single entry used for every pose. `threads`: size of a dedicated pool, or
/// the global pool when `None`. Each alignment has its own `Result`.
pub fn align_batch(
    scans: &[&[[f64; 2]]],
    index: &MapIndex,
    initial: &[Pose2],
    cfg: &IcpConfig,
    threads: Option<usize>,
) -> Result<Vec<Result<IcpResult>>> {
    cfg.validate()?;
    if scans.len() != initial.len() && scans.len() != 1 {
        return Err(IcpError::Shape {
            what: "scans".into(),
            expected: format!("1 or {} scans (one per initial pose)", initial.len()),
            got: format!("{} scans", scans.len()),
        });
    }
    let run = || -> Vec<Result<IcpResult>> {
        initial
            .par_iter()
            .enumerate()
            .map_init(Workspace::default, |ws, (k, pose)| {
                let scan = if scans.len() == 1 { scans[0] } else { scans[k] };
                check_inputs(scan, *pose, cfg)?;
                Ok(align_unchecked(scan, index, *pose, cfg, ws))
            })
            .collect()
    };
    match threads {
        None => Ok(run()),
        Some(0) => Err(bad("num_threads", 0, "must be at least 1")),
        Some(n) => {
            // more threads than a few per core (or than alignments) only costs: clamp
            let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
            let n = n
                .min(MAX_THREADS_PER_CORE * cores)
                .min(initial.len().max(1));
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| IcpError::Internal(format!("thread pool: {e}")))?;
            Ok(pool.install(run))
        }
    }
}

/// ICP from `initial` (from the initial position at the heading prior first, when the
/// prior disagrees with the initial heading by more than [`PRIOR_JUMP`]); then, unless the
/// result explains the scan, the cheap local checks (a place along the corridor, the
/// window at the heading prior) and, unless one of those explains it, the window search
/// around `initial` and ICP from its best poses: the pose that explains the scan best.
/// The map's histogram of line directions is built on the first call, its likelihood field
/// on the first that needs the window.
fn align_unchecked(
    scan: &[[f64; 2]],
    index: &MapIndex,
    initial: Pose2,
    cfg: &IcpConfig,
    ws: &mut Workspace,
) -> IcpResult {
    if !cfg.window_search {
        return align_plain(scan, index, initial, cfg, ws);
    }
    let center = initial.normalized();
    // the map's pieces, which the see-through check needs once a beam meets a wall: built
    // by the first call, not by whichever later one first meets a wall (a call that costs
    // a map-sized build at random: a caller's warm-up call makes the next ones steady)
    if cfg.vanished_object_size > 0.0 {
        index.objects();
    }
    // the heading at which the scan's walls line up with the map's (`None` without enough
    // straight wall pieces in the scan)
    let prior = local::scan_directions(scan).and_then(|h| {
        local::heading_prior(
            &h,
            index.line_directions(),
            center.theta,
            cfg.window_heading,
        )
    });
    // a start heading the prior disagrees with: ICP from the initial position at the
    // prior's heading first (plain ICP from a start ~10° off keeps most of the error among
    // racks and furniture, and the window search would run). That fit ends the search when
    // it explains the scan outright; one acceptable only by the looser rules (a tight or
    // occluded fit with a quarter of the scan unexplained) only when it moved at most
    // [`PRIOR_NEAR`] of the window and has no beams through walls — or, outside a
    // corridor with an RMS within `prior_sure_rms`, at most [`TIGHT_SEE_THROUGH`] (glass,
    // a car that left and a person beside it: on the garage's first 100 small starts
    // this halves those going on to the window, 18 -> 9, to the same poses) — and the ICP from the
    // initial pose does not rank better (a turned start can settle in a neighbouring room
    // or one door frame along)
    let mut plain_first = None;
    if let Some(th) = prior.filter(|th| wrap_angle(th - center.theta).abs() > PRIOR_JUMP) {
        let turned_cfg = IcpConfig {
            max_iterations: PRIOR_ITERATIONS.min(cfg.max_iterations),
            ..cfg.clone()
        };
        let start = Pose2::new(center.x, center.y, th);
        let mut turned = align_plain(scan, index, start, &turned_cfg, ws);
        let f = assessed(scan, index, &turned, cfg, ws);
        turned.fit = Some(f);
        let near = (turned.pose.x - center.x).hypot(turned.pose.y - center.y)
            <= PRIOR_NEAR * cfg.window_position;
        let candidate = turned.termination != Termination::TooFewInliers
            && acceptable(&turned, &f, center, cfg)
            && (explains(&f, cfg)
                || (near
                    && (through_walls(&f) <= cfg.accept_see_through
                        || (f.rms <= cfg.prior_sure_rms * cfg.expected_noise
                            && turned.degeneracy >= SLIDE_DEGENERACY
                            && through_walls(&f) <= TIGHT_SEE_THROUGH))));
        let wins = candidate
            && (explains(&f, cfg) || f.rms <= cfg.prior_sure_rms * cfg.expected_noise || {
                let mut p = align_plain(scan, index, initial, cfg, ws);
                let pf = assessed(scan, index, &p, cfg, ws);
                p.fit = Some(pf);
                let better = p.termination != Termination::TooFewInliers
                    && acceptable(&p, &pf, center, cfg)
                    && rank(&pf, cfg) > rank(&f, cfg);
                plain_first = Some(p);
                !better
            });
        if wins {
            let mut pick = Pick {
                best: turned.clone(),
                score: rank(&f, cfg),
                path: StartPath::Prior,
                tried: Vec::new(),
                floor: explained_floor(&turned, &f, cfg),
            };
            if let Some(mut r) = settle(scan, index, turned, center, cfg, ws, &mut pick) {
                if r.start == StartPath::Plain {
                    r.start = StartPath::Prior;
                }
                return r;
            }
        }
    }
    let plain = plain_first.unwrap_or_else(|| {
        let mut p = align_plain(scan, index, initial, cfg, ws);
        p.fit = Some(assessed(scan, index, &p, cfg, ws));
        p
    });
    let fit = plain.fit.expect("assessed above");
    // the plain fit competes on its fit like the window's refinements (an iteration limit
    // reached is still a pose); only one without enough inliers is out
    let plain_score = if plain.termination == Termination::TooFewInliers {
        -1.0
    } else {
        rank(&fit, cfg)
    };
    let mut pick = Pick {
        best: plain.clone(),
        score: plain_score,
        path: StartPath::Plain,
        tried: Vec::new(),
        floor: explained_floor(&plain, &fit, cfg),
    };
    if let Some(r) = settle(scan, index, plain, center, cfg, ws, &mut pick) {
        return r;
    }
    // no field (a map too large for its grid): nothing to search
    let Some(field) = index.likelihood_field() else {
        return pick.result();
    };
    // the heading at which the scan's walls line up with the map's: the window at a few
    // headings around it first (a fraction of the full window's cost), and the full window
    // only when nothing there explains the scan
    if let Some(th) = prior {
        let narrow_cfg = IcpConfig {
            window_heading: PRIOR_WINDOW_HEADING.min(cfg.window_heading),
            ..cfg.clone()
        };
        let narrow_center = Pose2::new(center.x, center.y, th);
        if let Some(win) = window::search(
            field,
            scan,
            narrow_center,
            &narrow_cfg,
            window::KEEP_RATIO,
            window::WINDOW_SEEDS,
        ) {
            refine_seeds(scan, index, field, &win.seeds, center, cfg, ws, &mut pick);
            if let Some(f) = pick.best.fit {
                if pick.path == StartPath::Window
                    && (acceptable(&pick.best, &f, center, cfg)
                        || searched_tight(&pick.best, &f, center, cfg))
                {
                    // in a corridor where the window could not tell its best place from
                    // another (its edge may cut the corridor between the truth and a
                    // place the seeds found), the places along it first, on the points
                    // that tell them apart
                    let mut cand = pick.best.clone();
                    cand.start = StartPath::Window;
                    let tie = win.second >= WINDOW_TIE * win.seeds[0].1;
                    let settled = if cand.degeneracy < SLIDE_DEGENERACY && !tie {
                        Some(cand)
                    } else {
                        slide_or_polish(scan, index, cand, f, center, cfg, ws, &mut pick)
                    };
                    if let Some(mut best) = settled {
                        best.window_score = Some(win.seeds[0].1);
                        best.window_second = Some(win.second);
                        return best;
                    }
                }
            }
        }
    }
    // the full window's seeds are refined afresh: near a wrong prior heading the narrow
    // window's seeds lie within `DISTINCT_ANGLE` of the right ones
    pick.tried.clear();
    let Some(win) = window::search(
        field,
        scan,
        center,
        cfg,
        window::KEEP_RATIO,
        window::WINDOW_SEEDS,
    ) else {
        return pick.result();
    };
    refine_seeds(scan, index, field, &win.seeds, center, cfg, ws, &mut pick);
    // no pose of the window explains the scan without beams through walls: the right one
    // may have scored well below the first pass's seeds on the pyramid (which cannot see
    // through-wall beams), so search the window again, wider, skipping the seeds tried
    let best_fit = pick.best.fit.unwrap_or(fit);
    if through_walls(&best_fit) > cfg.accept_see_through
        && !(pick.path == StartPath::Window && searched_tight(&pick.best, &best_fit, center, cfg))
    {
        if let Some(wide) = window::search(
            field,
            scan,
            center,
            cfg,
            window::WIDE_KEEP_RATIO,
            window::WIDE_SEEDS,
        ) {
            refine_seeds(scan, index, field, &wide.seeds, center, cfg, ws, &mut pick);
        }
    }
    let mut best = pick.result();
    best.window_score = Some(win.seeds[0].1);
    best.window_second = Some(win.second);
    best
}

/// The look along a corridor reaches this far (m) beyond the window (a start error of
/// exactly `window_position` puts the truth at the window's edge, and a place counts only
/// as a local maximum inside the range).
const SLIDE_REACH: f64 = 0.25;
/// Scan points (evenly subsampled) the look along a corridor scores.
const SLIDE_POINTS: usize = 64;
/// The ICP starts at the heading prior instead of the initial heading when the two differ
/// by more than this (rad): plain ICP converges from a few degrees, and the prior's error
/// is about half a degree (median; p95 1.4-8° on the four families' small starts).
const PRIOR_JUMP: f64 = 0.05;
/// The ICP from the heading prior stops after this many iterations at most: from the right
/// heading it converges in a few (on the four families' small starts the plain ICP's median
/// is 6, p95 13), and one that needs more is left to the ICP from the initial pose and the
/// window (from a large start it would mostly cost).
const PRIOR_ITERATIONS: usize = 15;
/// See [`align_unchecked`]: a fit from the heading prior that moved at most this fraction
/// of `window_position` from the initial position is accepted by the looser rules.
const PRIOR_NEAR: f64 = 0.5;
/// Half-width (rad) of the window searched first, around the heading prior.
const PRIOR_WINDOW_HEADING: f64 = 0.07;
/// A place along the corridor replaces the fit when its fit scores this much more (in
/// [0, 1]): in a corridor without features along it every place scores the same, and the
/// fit from the initial pose is kept.
const SLIDE_MARGIN: f64 = 0.005;

/// A fit `r` (its `fit` set) that explains the scan ([`acceptable`]) is the result: outside
/// corridors as it is (polished when its RMS is loose, see [`POLISH_RMS`]); in a corridor
/// (degeneracy below [`SLIDE_DEGENERACY`]) the best of it and the ICP refinements of the
/// other places along the corridor that score about as well ([`local::slide_candidates`]),
/// when that one explains the scan. Every pose tried competes in `pick`; `None` when none
/// explains the scan.
#[allow(clippy::too_many_arguments)]
fn settle(
    scan: &[[f64; 2]],
    index: &MapIndex,
    r: IcpResult,
    center: Pose2,
    cfg: &IcpConfig,
    ws: &mut Workspace,
    pick: &mut Pick,
) -> Option<IcpResult> {
    let fit = r.fit?;
    let ok = acceptable(&r, &fit, center, cfg);
    if r.termination != Termination::TooFewInliers && pick.beaten_by(&fit, rank(&fit, cfg)) {
        pick.score = rank(&fit, cfg);
        pick.best = r.clone();
        pick.path = StartPath::Local;
    }
    if !ok {
        return None;
    }
    slide_or_polish(scan, index, r, fit, center, cfg, ws, pick)
}

/// A narrow-window result in a corridor gets the look along the corridor (on the points
/// that tell places apart, [`slide_points`]) when the window's best distinct alternative
/// scored at least this fraction of its best (on the clinic's large starts, a place
/// 1.28 m along the corridor from the truth with a window score of 0.53 / 0.53).
const WINDOW_TIE: f64 = 0.97;

/// The accepted fit `r` (with fit `fit`) outside a corridor, polished ([`polished`]); in a
/// corridor the best of it and the places along the corridor ([`settle`]); `None` when a
/// place along the corridor scores better and does not explain the scan.
#[allow(clippy::too_many_arguments)]
fn slide_or_polish(
    scan: &[[f64; 2]],
    index: &MapIndex,
    r: IcpResult,
    fit: Fit,
    center: Pose2,
    cfg: &IcpConfig,
    ws: &mut Workspace,
    pick: &mut Pick,
) -> Option<IcpResult> {
    if r.degeneracy >= SLIDE_DEGENERACY {
        return Some(polished(scan, index, r, fit, cfg, ws));
    }
    // the window's slice along the corridor through the fit
    let dir = r.degenerate_direction;
    let along = (r.pose.x - center.x) * dir[0] + (r.pose.y - center.y) * dir[1];
    // the places along the corridor that score best on an even subsample of the scan, and
    // those that score best on the points that tell places apart ([`slide_points`]): the
    // first is blind to the few door jambs that differ, the second can be led by people
    // (unmapped returns that some other place explains); every candidate is refined and
    // competes on the whole scan's fit (on the clinic's small starts a fit 0.39 m along a
    // corridor from the truth, whose one small feature only the second sees)
    let range = (
        -cfg.window_position - SLIDE_REACH - along,
        cfg.window_position + SLIDE_REACH - along,
    );
    let (telling, picked) = slide_points(scan, index, r.pose, dir, cfg);
    // the even subsample is the picked part of the telling points (in scan order) unless
    // it has fewer than 3 points (then it is the whole scan): both lists from one pass
    let (mut cands, told) = if picked.iter().filter(|&&b| b).count() >= 3 {
        let (telling_cands, even_cands) = local::slide_candidates_of(
            index,
            &telling,
            Some(&picked),
            r.pose,
            dir,
            range,
            cfg.expected_noise,
        );
        (even_cands, telling_cands)
    } else {
        let even = window::subsample(scan, scan.len().div_ceil(SLIDE_POINTS), 3);
        (
            local::slide_candidates(index, &even, r.pose, dir, range, cfg.expected_noise),
            local::slide_candidates(index, &telling, r.pose, dir, range, cfg.expected_noise),
        )
    };
    for c in told {
        if cands
            .iter()
            .all(|o| (o.x - c.x).hypot(o.y - c.y) > local::SLIDE_STEP * 1.5)
        {
            cands.push(c);
        }
    }
    // a candidate lies within half a cell of its place: the final threshold from the start
    // (a wider one would pull it back to the fit's own place along the corridor)
    let slide_cfg = IcpConfig {
        max_correspondence_distance: cfg.min_correspondence_distance,
        heading_search: 0.0,
        position_search: 0.0,
        ..cfg.clone()
    };
    let (mut best, mut best_fit, mut moved) = (r, fit, false);
    for c in cands {
        let mut rr = align_plain(scan, index, c, &slide_cfg, ws);
        if rr.termination == Termination::TooFewInliers {
            continue;
        }
        let ff = assessed(scan, index, &rr, cfg, ws);
        rr.fit = Some(ff);
        if rank(&ff, cfg) > rank(&best_fit, cfg) + SLIDE_MARGIN {
            (best, best_fit, moved) = (rr, ff, true);
        }
    }
    if moved {
        if pick.beaten_by(&best_fit, rank(&best_fit, cfg)) {
            pick.score = rank(&best_fit, cfg);
            pick.best = best.clone();
            pick.path = StartPath::Local;
        }
        if !acceptable(&best, &best_fit, center, cfg) {
            return None;
        }
        best.start = StartPath::Local;
    }
    Some(polished(scan, index, best, best_fit, cfg, ws))
}

/// The scan points the look along a corridor scores: an even subsample of about
/// [`SLIDE_POINTS`], and every point that is not on a wall along the corridor at `pose`
/// (near a map point whose normal is more than 60° from `dir`): door jambs, columns and
/// furniture ends are what tell the places along a corridor apart — at a wrong place their
/// returns lie off the map — and a subsample keeps few of them (on the clinic a place
/// 1.3 m along the corridor from the truth scored within 0.2 % of it on 64 points, 2 %
/// below it on the whole scan). With them, a flag per point: in the even subsample.
fn slide_points(
    scan: &[[f64; 2]],
    index: &MapIndex,
    pose: Pose2,
    dir: [f64; 2],
    cfg: &IcpConfig,
) -> (Vec<[f64; 2]>, Vec<bool>) {
    let stride = scan.len().div_ceil(SLIDE_POINTS);
    let pick = window::Picker::new(stride);
    let normals = index.normals();
    let near = 3.0 * cfg.expected_noise + 2.0 * index.spacing();
    let mut out = Vec::new();
    let mut picked = Vec::new();
    for p in scan {
        if pick.picked(p) {
            out.push(*p);
            picked.push(true);
            continue;
        }
        let (d2, j) = index.correspondence(pose.transform(*p));
        let n = normals[j];
        if d2 > near * near || (n[0] * dir[0] + n[1] * dir[1]).abs() >= SLIDE_ACROSS_COS {
            out.push(*p);
            picked.push(false);
        }
    }
    if out.len() < 3 {
        out = scan.to_vec();
        picked = scan.iter().map(|p| pick.picked(p)).collect();
    }
    (out, picked)
}

/// See [`slide_points`]: cos 60°.
const SLIDE_ACROSS_COS: f64 = 0.5;

/// An accepted fit whose inliers' RMS exceeds this many `expected_noise` gets the
/// polishing ICP ([`polish`]): on the clinic, people near walls can hold the ICP a few
/// tenths of a degree off with an RMS of 0.6 σ, where the polish settles on the truth.
const POLISH_RMS: f64 = 0.5;

/// `r` with fit `fit`, or its polished version when the RMS is loose and the polish scores
/// better.
fn polished(
    scan: &[[f64; 2]],
    index: &MapIndex,
    mut r: IcpResult,
    fit: Fit,
    cfg: &IcpConfig,
    ws: &mut Workspace,
) -> IcpResult {
    if fit.rms > POLISH_RMS * cfg.expected_noise {
        if let Some((mut p, pf)) = polish(scan, index, r.pose, fit.score, cfg, ws) {
            p.fit = Some(pf);
            p.start = r.start;
            return p;
        }
    }
    r.fit = Some(fit);
    r
}

/// Pairs of the polishing ICP lie within this many `expected_noise` of the map.
const POLISH_BAND: f64 = 3.0;
/// Iterations of the polishing ICP at most.
const POLISH_ITERATIONS: usize = 10;

/// A last ICP from `pose` with the pairs limited to [`POLISH_BAND`] σ of the expected noise
/// and Cauchy weights of scale σ (close to the fit score's own Gaussian kernel): on the
/// clinic the refinement with the wider thresholds settles a few centimetres or tenths of
/// a degree off when people stand near walls, and the score is higher where this one
/// settles. The polished result and its fit, when its fit scores better than `score`.
fn polish(
    scan: &[[f64; 2]],
    index: &MapIndex,
    pose: Pose2,
    score: f64,
    cfg: &IcpConfig,
    ws: &mut Workspace,
) -> Option<(IcpResult, Fit)> {
    let band = (POLISH_BAND * cfg.expected_noise).min(cfg.max_correspondence_distance);
    let pcfg = IcpConfig {
        max_correspondence_distance: band,
        min_correspondence_distance: band,
        threshold_decay: 1.0,
        robust: Robust::Cauchy,
        robust_scale: cfg.expected_noise,
        max_iterations: POLISH_ITERATIONS.min(cfg.max_iterations),
        heading_search: 0.0,
        position_search: 0.0,
        ..cfg.clone()
    };
    let r = align_plain(scan, index, pose, &pcfg, ws);
    if r.termination == Termination::TooFewInliers {
        return None;
    }
    let f = assessed(scan, index, &r, cfg, ws);
    (f.score > score).then_some((r, f))
}

/// The ranking of candidate poses: the fit's score, times `TIGHT_REF · expected_noise /
/// rms` when the inliers' RMS exceeds `TIGHT_REF · expected_noise`. A right fit's RMS is
/// the range noise; on the clinic and the apartment the wrong poses that outscore the
/// truth (people and furniture ends make up for a door frame) do so with an RMS of
/// 0.55-1 σ against the truth's 0.4-0.55 σ.
fn rank(fit: &Fit, cfg: &IcpConfig) -> f64 {
    let knee = TIGHT_REF * cfg.expected_noise;
    if fit.rms > knee {
        fit.score * knee / fit.rms
    } else {
        fit.score
    }
}

/// See [`rank`].
const TIGHT_REF: f64 = 0.5;

/// The best pose so far among the plain fit and the window's refinements.
struct Pick {
    best: IcpResult,
    /// its [`rank`]
    score: f64,
    /// where it came from: the plain fit, a place along a corridor, or a window seed
    path: StartPath,
    /// seeds already refined
    tried: Vec<Pose2>,
    /// the least inlier share a pose must have to replace the best: set when the fit the
    /// search started from is near-exact ([`explained_floor`])
    floor: Option<f64>,
}

/// A fit the verified start begins from that is near-exact — at least
/// `accept_inlier_ratio` of the scan within the band and an RMS of at most [`TIGHT_RMS`]
/// `expected_noise` — is replaced only by a pose that explains at least [`FLOOR_SHARE`] as
/// much of the scan (the floor returned), however its beams through walls rank it: the
/// see-through test reads any map point a beam passes within half a sample spacing of as
/// a wall, which isolated points (poles, legs, a sparse or scattered map) and walls the
/// map has and the world no longer has (a door closed when mapped) are not. A pose that
/// leaves most of the scan the exact fit explains unexplained is not a better answer.
/// (Found by `prop_rigid_transform_recovered`: on 150 scattered points 0.4 m apart the exact
/// fit had 97.5 % of its beams "through walls", and a window pose with 21 % inliers won.)
fn explained_floor(r: &IcpResult, fit: &Fit, cfg: &IcpConfig) -> Option<f64> {
    (r.termination != Termination::TooFewInliers
        && fit.inlier_ratio >= cfg.accept_inlier_ratio
        && fit.rms <= TIGHT_RMS * cfg.expected_noise)
        .then_some(FLOOR_SHARE * fit.inlier_ratio)
}

/// See [`explained_floor`].
const FLOOR_SHARE: f64 = 0.5;

impl Pick {
    /// Does a pose with fit `f` (ranked `score`) replace the best?
    fn beaten_by(&self, f: &Fit, score: f64) -> bool {
        score > self.score && self.floor.is_none_or(|m| f.inlier_ratio >= m)
    }

    /// The best pose as the result of a verified start that did not accept the plain fit
    /// as it was (the plain fit itself: `WindowKeptPlain`).
    fn result(self) -> IcpResult {
        let mut best = self.best;
        best.start = match self.path {
            StartPath::Plain => StartPath::WindowKeptPlain,
            p => p,
        };
        best
    }
}

/// Rank the coarse `seeds` not yet tried by how well they explain the scan (see-through included: the
/// pyramid's likelihood alone cannot tell a pose whose beams pass through walls), with the
/// noise widened to the lattice's error; refine the best few by ICP, polish each whose
/// RMS is loose ([`polish`], [`POLISH_RMS`]), and keep the one whose fit scores best in
/// `pick` (stopping early once one explains the scan and the next ranks well below it,
/// [`RANK_GAP`]).
#[allow(clippy::too_many_arguments)]
fn refine_seeds(
    scan: &[[f64; 2]],
    index: &MapIndex,
    field: &crate::likelihood::LikelihoodField,
    seeds: &[(Pose2, f64)],
    center: Pose2,
    cfg: &IcpConfig,
    ws: &mut Workspace,
    pick: &mut Pick,
) {
    let coarse_cfg = IcpConfig {
        expected_noise: cfg.expected_noise.max(0.5 * field.resolution() + 0.025),
        ..cfg.clone()
    };
    let sub = window::subsample(scan, scan.len().div_ceil(window::RANKING_POINTS), 3);
    // the score is the distances' likelihood times the see-through factor (at most 1): the
    // see-through (the costly part) only for seeds whose likelihood could still reach the
    // best few, which gives exactly the ranking of scoring them all
    let mut bounds: Vec<(f64, Pose2)> = seeds
        .iter()
        .filter(|(seed, _)| pick.tried.iter().all(|t| window::distinct(seed, t)))
        .map(|&(seed, _)| (window::distances(&sub, index, seed, &coarse_cfg).2, seed))
        .collect();
    bounds.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut ranked: Vec<(f64, Pose2)> = Vec::new();
    for (bound, seed) in bounds {
        // one more than are refined: the early stop compares with the next seed
        if ranked.len() > window::WINDOW_REFINED && bound < ranked[window::WINDOW_REFINED].0 {
            break;
        }
        let score = bound * (1.0 - window::see_through(&sub, index, seed)).powi(2);
        let at = ranked.partition_point(|r| r.0 >= score);
        ranked.insert(at, (score, seed));
    }
    let refine_cfg = refine_config(field, cfg);
    for (k, &(seed_rank, seed)) in ranked.iter().take(window::WINDOW_REFINED).enumerate() {
        pick.tried.push(seed);
        let mut r = align_plain(scan, index, seed, &refine_cfg, ws);
        // an iteration limit reached from a good seed is still a pose: the fit decides
        if r.termination == Termination::TooFewInliers {
            continue;
        }
        let mut f = assessed(scan, index, &r, cfg, ws);
        if f.rms > POLISH_RMS * cfg.expected_noise {
            if let Some((p, pf)) = polish(scan, index, r.pose, f.score, cfg, ws) {
                (r, f) = (p, pf);
            }
        }
        let accepted = acceptable(&r, &f, center, cfg) && r.degeneracy >= SLIDE_DEGENERACY;
        if pick.beaten_by(&f, rank(&f, cfg)) {
            r.fit = Some(f);
            pick.score = rank(&f, cfg);
            pick.best = r;
            pick.path = StartPath::Window;
        }
        // this seed explains the scan outside a corridor, and the next ranks well below it:
        // the rest would only cost
        let next = ranked.get(k + 1).map_or(0.0, |n| n.0);
        if accepted
            && pick.path == StartPath::Window
            && pick.score == rank(&f, cfg)
            && next < RANK_GAP * seed_rank
        {
            break;
        }
    }
}

/// Seeds ranking below this fraction of a refined seed that explains the scan (outside a
/// corridor) are not refined.
const RANK_GAP: f64 = 0.85;

/// The ICP of a start within a lattice step of its optimum (a window seed, a place along
/// a corridor): a wide first threshold would only let clutter pull it away.
fn refine_config(field: &crate::likelihood::LikelihoodField, cfg: &IcpConfig) -> IcpConfig {
    IcpConfig {
        max_correspondence_distance: (4.0 * field.resolution()).clamp(
            cfg.min_correspondence_distance,
            cfg.max_correspondence_distance,
        ),
        heading_search: 0.0,
        position_search: 0.0,
        ..cfg.clone()
    }
}

/// Below this degeneracy (λ_min / λ_max of the translational information) a fit lies in
/// a corridor or an aisle, where ICP from a start a few decimetres off can converge along
/// it to a pose that explains most of the scan but not all of it (on the Python scan model
/// of the warehouse, 5 of 100 small-start fits slid 0.16-1.1 m down an aisle and passed the
/// fit check): such fits are compared with the other places along the corridor.
const SLIDE_DEGENERACY: f64 = 0.25;

/// A fit with no more see-through than `accept_see_through` and a tight RMS (at most this times
/// `expected_noise`) explains the scan with fewer inliers: the rest are returns from
/// unmapped things in front of the walls (people, clutter), not a misalignment, which
/// would spread the inliers' distances over the band and let beams through walls. On the
/// tuned families (clinic, warehouse, office; 200 cases each, 1 cm range noise) the
/// right plain fits have an RMS below 1 cm, the wrong ones that are not corridor slides
/// 1.2 cm or more.
const OCCLUDED_RMS: f64 = 0.75;
/// ... and at least this share of inliers.
const OCCLUDED_INLIER_RATIO: f64 = 0.55;

/// A tight fit explains the scan with fewer inliers and some beams through mapped walls:
/// an RMS of at most this many `expected_noise` ...
const TIGHT_RMS: f64 = 0.6;
/// ... at least this share of inliers ...
const TIGHT_INLIER_RATIO: f64 = 0.5;
/// ... and at most this share of beams through mapped walls (mapped glass lets half the
/// beams through: on the clinic the right fits behind its glass fronts have 6-13 %). On
/// the four families (200 cases each, both starts, 1 cm range noise) the right plain fits
/// have an RMS below 0.6 σ; the wrong ones that are that tight lie in corridors (see
/// [`SLIDE_DEGENERACY`]: the places along it are compared), or turned beyond the window.
const TIGHT_SEE_THROUGH: f64 = 0.15;

/// Does `r` (with fit `fit`) explain the scan: a fit that converged (or one of a tight RMS
/// at the iteration limit) within the window around `center` that [`explains`] the scan,
/// explains it as occluded ([`OCCLUDED_RMS`]) or is tight ([`TIGHT_RMS`])?
fn acceptable(r: &IcpResult, fit: &Fit, center: Pose2, cfg: &IcpConfig) -> bool {
    // in a corridor a fit with beams through walls may be another room's (the look along
    // the corridor cannot move it across): there the see-through limit of `cfg` holds
    let see_limit = if r.degeneracy >= SLIDE_DEGENERACY {
        TIGHT_SEE_THROUGH
    } else {
        cfg.accept_see_through
    };
    // beams through small mapped objects that the scan does not see at all (cars that
    // have left) do not count against a tight fit: its RMS and inliers already say the
    // pose is right, and a misaligned pose's beams cross the walls
    let tight = fit.rms <= TIGHT_RMS * cfg.expected_noise
        && fit.inlier_ratio >= TIGHT_INLIER_RATIO
        && through_walls(fit) <= see_limit;
    let occl = fit.inlier_ratio >= OCCLUDED_INLIER_RATIO
        && fit.see_through <= cfg.accept_see_through
        && fit.rms <= OCCLUDED_RMS * cfg.expected_noise;
    let settled = r.converged || (r.termination == Termination::MaxIterations && tight);
    settled && inside(r, center, cfg) && (explains(fit, cfg) || occl || tight)
}

/// After a window search: a window pose `r` (with fit `fit`) whose inliers fit tightly —
/// an RMS of at most [`TIGHT_REF`] `expected_noise` (the knee of [`rank`]) and at least [`TIGHT_INLIER_RATIO`] of
/// the scan — explains the scan with up to [`SEARCHED_SEE_THROUGH`] of its beams through
/// mapped walls, in a corridor too: the window has been searched for the other places
/// (where [`acceptable`] has to allow for places it has not looked at), and mapped glass
/// lets beams through (on the clinic the right poses behind its two glass fronts have
/// 6-21 % of the beams through walls at an RMS of 0.37-0.43 σ; the wrong poses the wide
/// pass corrected had an RMS above 1 σ; on the held-out apartment a pose turned by the 45°
/// wall had 0.57 σ, 14 % through walls, which a limit of 0.6 σ accepted).
fn searched_tight(r: &IcpResult, fit: &Fit, center: Pose2, cfg: &IcpConfig) -> bool {
    fit.rms <= TIGHT_REF * cfg.expected_noise
        && fit.inlier_ratio >= TIGHT_INLIER_RATIO
        && through_walls(fit) <= SEARCHED_SEE_THROUGH
        && r.converged
        && inside(r, center, cfg)
}

/// See [`searched_tight`].
const SEARCHED_SEE_THROUGH: f64 = 0.25;

/// Is `r` within the window around `center` (plus the final threshold and a heading step)?
fn inside(r: &IcpResult, center: Pose2, cfg: &IcpConfig) -> bool {
    let reach = cfg.window_position + cfg.min_correspondence_distance;
    (r.pose.x - center.x).abs() <= reach
        && (r.pose.y - center.y).abs() <= reach
        && wrap_angle(r.pose.theta - center.theta).abs()
            <= cfg.window_heading + cfg.window_angle_step
}

/// The share of `fit`'s checked beams through mapped walls, not counting those through
/// small mapped objects the scan does not see at all ([`Fit::vanished`]: objects that left
/// since mapping).
fn through_walls(fit: &Fit) -> f64 {
    fit.see_through - fit.vanished
}

/// Does `fit` explain the scan, by the acceptance settings of `cfg`?
fn explains(fit: &Fit, cfg: &IcpConfig) -> bool {
    fit.inlier_ratio >= cfg.accept_inlier_ratio
        && fit.see_through <= cfg.accept_see_through
        && fit.rms <= 2.0 * cfg.expected_noise
}

/// The ICP proper (with the optional heading/position start search), from `initial`.
fn align_plain(
    scan: &[[f64; 2]],
    index: &MapIndex,
    initial: Pose2,
    cfg: &IcpConfig,
    ws: &mut Workspace,
) -> IcpResult {
    let n = scan.len();
    let normals = if cfg.metric == Metric::PointToLine {
        Some(index.normals())
    } else {
        None
    };
    let map = index.points();
    let final_thr = cfg.final_threshold();
    let min_inl = cfg
        .min_inliers
        .max((cfg.min_inlier_ratio * n as f64).ceil() as usize);

    let mut pose = initial.normalized();
    if cfg.heading_search > 0.0 || cfg.position_search > 0.0 {
        pose = heading_search(scan, index, pose, cfg, ws);
    }
    let mut mse = f64::INFINITY;
    // point-to-point's acceleration (point-to-line does not use it: its scale, a pass
    // with two divisions per point, is not computed)
    let mut accel = normals.is_none().then(|| Accelerator::new(scan));
    let mut iterations = 0;
    let mut termination = Termination::MaxIterations;
    ws.moved.resize(n, [0.0; 2]);
    ws.nn.resize(n, 0);
    // room for every point's pair and query up front (no regrowth in the loop)
    ws.pairs.reserve(n);
    ws.queries.reserve(n);
    ws.answers.reserve(n);
    ws.nn_pose = None;
    ws.reach = scan
        .iter()
        .map(|p| p[0] * p[0] + p[1] * p[1])
        .fold(0.0, f64::max)
        .sqrt();

    // The coarse stages (threshold above its final value) see an even subsample of the
    // scan (about `COARSE_POINTS`, chosen by the points themselves, so not by their order):
    // at a threshold of decimetres the step is set by the walls' directions, not by the
    // range noise, and a few dozen points per wall give it; the final stage sees every point.
    let stride = n / COARSE_POINTS;
    ws.coarse.clear();
    if stride >= 2 {
        let pick = window::Picker::new(stride);
        ws.coarse
            .extend((0..n).filter(|&i| pick.picked(&scan[i])).map(|i| i as u32));
    }
    // fewer pairs than this in a coarse stage: that stage and the rest see every point
    let coarse_min = (min_inl * ws.coarse.len())
        .div_ceil(n.max(1))
        .max(COARSE_MIN_PAIRS);
    let mut coarse = ws.coarse.len() >= 2 * coarse_min;
    let mut last_coarse = false;

    // The threshold shrinks one stage per iteration for point-to-line (which settles in one
    // or two steps at any threshold); point-to-point creeps along walls, so its threshold
    // shrinks only once it has settled at the current one (a step below 1 mm and 1 mrad):
    // shrinking sooner strands it with too few pairs in a local minimum.
    let mut stage = 0usize;
    let mut used_thr = cfg.threshold_at(0);
    for k in 0..cfg.max_iterations {
        iterations = k + 1;
        let thr = cfg.threshold_at(stage);
        used_thr = thr;
        let thr2 = thr * thr;
        let at_final = (thr - final_thr).abs() <= 1e-12 * final_thr.max(1.0);

        // (a) closest points, with the distance threshold
        let Workspace {
            pairs,
            moved,
            coarse: sub,
            nn,
            nn_pose,
            queries,
            answers,
            ..
        } = &mut *ws;
        let mut buf = (queries, answers);
        pairs.clear();
        last_coarse = coarse && !at_final;
        if last_coarse {
            gather(
                scan,
                index,
                pose,
                thr2,
                Some(sub),
                pairs,
                moved,
                nn,
                &mut buf,
            );
            *nn_pose = None;
            if pairs.len() < coarse_min {
                coarse = false;
                last_coarse = false;
            }
        }
        if !last_coarse {
            pairs.clear();
            gather(scan, index, pose, thr2, None, pairs, moved, nn, &mut buf);
            *nn_pose = Some(pose);
        }
        trim(&mut ws.pairs, cfg.trim_fraction);
        // a coarse stage's subsample needs its share of the inliers, not the whole scan's
        if ws.pairs.len() < if last_coarse { coarse_min } else { min_inl } {
            termination = Termination::TooFewInliers;
            mse = if ws.pairs.is_empty() {
                f64::INFINITY
            } else {
                ws.pairs.iter().map(|p| p.d2).sum::<f64>() / ws.pairs.len() as f64
            };
            break;
        }

        // (b) solve
        let (new_pose, cur_mse) = match normals {
            None => {
                let mut cc = CrossCovariance::default();
                let mut sum = 0.0;
                for pr in &ws.pairs {
                    let w = robust_weight(cfg.robust, cfg.robust_scale, pr.d2.sqrt());
                    cc.add(scan[pr.i as usize], map[pr.j as usize], w);
                    sum += pr.d2;
                }
                let m = sum / ws.pairs.len() as f64;
                match cc.solve() {
                    Some(reg) => {
                        let mut np = Pose2::new(reg.t[0], reg.t[1], wrap_angle(reg.theta));
                        let accel = accel.as_mut().expect("made for point-to-point");
                        if at_final {
                            np = accel.step(np, registered_mse(scan, map, &ws.pairs, np));
                        } else {
                            accel.reset();
                        }
                        (np, m)
                    }
                    None => (pose, m),
                }
            }
            Some(nrm) => {
                // H = Σ w·J·Jᵀ by its six distinct terms (each the product J_a·J_b·w of
                // the full outer product, summed in the same order: the same H)
                let mut hs = [0.0f64; 6];
                let mut gs = [0.0f64; 3];
                let mut sum = 0.0;
                for pr in &ws.pairs {
                    let q = ws.moved[pr.i as usize];
                    let x = map[pr.j as usize];
                    let nv = nrm[pr.j as usize];
                    let r = nv[0] * (q[0] - x[0]) + nv[1] * (q[1] - x[1]);
                    let dq = [q[0] - pose.x, q[1] - pose.y];
                    let jac = [nv[0], nv[1], nv[1] * dq[0] - nv[0] * dq[1]];
                    let w = robust_weight(cfg.robust, cfg.robust_scale, r);
                    hs[0] += jac[0] * jac[0] * w;
                    hs[1] += jac[0] * jac[1] * w;
                    hs[2] += jac[0] * jac[2] * w;
                    hs[3] += jac[1] * jac[1] * w;
                    hs[4] += jac[1] * jac[2] * w;
                    hs[5] += jac[2] * jac[2] * w;
                    let wr = w * r;
                    gs[0] += jac[0] * wr;
                    gs[1] += jac[1] * wr;
                    gs[2] += jac[2] * wr;
                    sum += r * r;
                }
                let h = Matrix3::new(
                    hs[0], hs[1], hs[2], hs[1], hs[3], hs[4], hs[2], hs[4], hs[5],
                );
                let g = Vector3::new(gs[0], gs[1], gs[2]);
                let m = sum / ws.pairs.len() as f64;
                let step = solve_step(&h, &g, thr);
                (
                    Pose2::new(
                        pose.x + step[0],
                        pose.y + step[1],
                        wrap_angle(pose.theta + step[2]),
                    ),
                    m,
                )
            }
        };

        let dt = ((new_pose.x - pose.x).powi(2) + (new_pose.y - pose.y).powi(2)).sqrt();
        let dth = wrap_angle(new_pose.theta - pose.theta).abs();
        if normals.is_some() || (dt < 1e-3 && dth < 1e-3) {
            stage += 1;
        }
        pose = new_pose;
        let prev_mse = std::mem::replace(&mut mse, cur_mse);

        // (d) termination (a coarse stage's MSE is of a subsample: not the paper's rule)
        if cur_mse < cfg.mse_threshold && !last_coarse {
            termination = Termination::MseBelowThreshold;
            break;
        }
        if at_final {
            // point-to-line: the Gauss-Newton step on pairs that hold converges about
            // quadratically (the next step is about the square of this one, in m and rad),
            // so a step below √tolerance leaves the pose within about the tolerance of
            // where the next step would have taken it
            let tol = if normals.is_some() {
                cfg.step_tolerance.sqrt().min(QUADRATIC_STOP)
            } else {
                cfg.step_tolerance
            };
            if dt <= tol && dth <= tol {
                termination = Termination::StepBelowTolerance;
                break;
            }
            if prev_mse.is_finite() && (prev_mse - cur_mse).abs() <= cfg.mse_change * prev_mse {
                termination = Termination::MseChangeBelowEpsilon;
                break;
            }
        }
    }

    // stopped in a coarse stage (an iteration limit): the pairs of every point at the
    // final pose, so that the inliers, MSE and covariance are the whole scan's
    // (at the threshold of the iteration that stopped, trimmed as every iteration is)
    if last_coarse {
        let thr = used_thr;
        let (s, c) = pose.theta.sin_cos();
        ws.pairs.clear();
        for (i, p) in scan.iter().enumerate() {
            let q = [pose.x + c * p[0] - s * p[1], pose.y + s * p[0] + c * p[1]];
            let (d2, j) = index.correspondence(q);
            ws.nn[i] = j as u32;
            if d2 <= thr * thr {
                ws.pairs.push(Pair {
                    i: i as u32,
                    j: j as u32,
                    d2,
                });
            }
        }
        ws.nn_pose = Some(pose);
        trim(&mut ws.pairs, cfg.trim_fraction);
        let sum: f64 = ws
            .pairs
            .iter()
            .map(|pr| match normals {
                Some(nrm) => {
                    let p = scan[pr.i as usize];
                    let q = [pose.x + c * p[0] - s * p[1], pose.y + s * p[0] + c * p[1]];
                    let (x, nv) = (map[pr.j as usize], nrm[pr.j as usize]);
                    (nv[0] * (q[0] - x[0]) + nv[1] * (q[1] - x[1])).powi(2)
                }
                None => pr.d2,
            })
            .sum();
        mse = if ws.pairs.is_empty() {
            f64::INFINITY
        } else {
            sum / ws.pairs.len() as f64
        };
    }
    let (information, covariance, degeneracy, direction) =
        uncertainty(scan, index, pose, &ws.pairs, cfg);
    IcpResult {
        pose,
        converged: termination.converged(),
        iterations,
        mse,
        inliers: ws.pairs.len(),
        num_points: n,
        covariance,
        information,
        degeneracy,
        degenerate_direction: direction,
        termination,
        start: StartPath::Plain,
        fit: None,
        window_score: None,
        window_second: None,
    }
}

/// The point-to-line stop on a step below √`step_tolerance` uses at most this (m, rad).
const QUADRATIC_STOP: f64 = 1e-3;

/// The trimmed variant: keep the best `fraction` of the pairs (by squared distance; at
/// least 3).
fn trim(pairs: &mut Vec<Pair>, fraction: f64) {
    if fraction < 1.0 && pairs.len() > 3 {
        let keep = ((fraction * pairs.len() as f64).ceil() as usize).clamp(3, pairs.len());
        if keep < pairs.len() {
            pairs.select_nth_unstable_by(keep - 1, |a, b| a.d2.total_cmp(&b.d2));
            pairs.truncate(keep);
        }
    }
}

/// Scan points (about) that the ICP's coarse stages see: see [`align_plain`].
const COARSE_POINTS: usize = 96;
/// A coarse stage needs at least this many pairs (and the scaled `min_inliers`).
const COARSE_MIN_PAIRS: usize = 12;

/// The pairs of the scan points `sub` (all of them when `None`) moved to `pose` within
/// `sqrt(thr2)` of their closest map points (`moved`: the moved points, `nn`: their closest
/// map points, by scan index; `buf`: room for a subsample's queries and the answers of
/// [`MapIndex::correspondences`]).
#[inline]
#[allow(clippy::too_many_arguments)]
fn gather(
    scan: &[[f64; 2]],
    index: &MapIndex,
    pose: Pose2,
    thr2: f64,
    sub: Option<&[u32]>,
    pairs: &mut Vec<Pair>,
    moved: &mut [[f64; 2]],
    nn: &mut [u32],
    buf: &mut (&mut Vec<[f64; 2]>, &mut Vec<(f64, u32)>),
) {
    let (s, c) = pose.theta.sin_cos();
    let (queries, answers) = buf;
    let n = scan.len();
    // every point: the moved points are the queries, in place; a subsample: its moved
    // points gathered into `queries`
    let qs: &[[f64; 2]] = match sub {
        None => {
            for (m, p) in moved[..n].iter_mut().zip(scan) {
                *m = [pose.x + c * p[0] - s * p[1], pose.y + s * p[0] + c * p[1]];
            }
            &moved[..n]
        }
        Some(ids) => {
            queries.clear();
            for &i in ids {
                let p = scan[i as usize];
                let q = [pose.x + c * p[0] - s * p[1], pose.y + s * p[0] + c * p[1]];
                moved[i as usize] = q;
                queries.push(q);
            }
            queries
        }
    };
    // room for the answers (each is written by the look-up before it is read)
    if answers.len() < qs.len() {
        answers.resize(qs.len(), (0.0, 0));
    }
    let answers = &mut answers[..qs.len()];
    // a threshold within the grid's reach rejects every point farther than the reach: no
    // exact answer for those (their closest point stays unknown until a fit needs it)
    if thr2 <= crate::index::CACHE_REACH * crate::index::CACHE_REACH {
        index.correspondences_within_reach(qs, answers);
    } else {
        index.correspondences(qs, answers);
    }
    let mut keep = |i: usize, (d2, j): (f64, u32)| {
        nn[i] = j;
        if d2 <= thr2 {
            pairs.push(Pair { i: i as u32, j, d2 });
        }
    };
    match sub {
        None => {
            for (i, &a) in answers.iter().enumerate() {
                keep(i, a);
            }
        }
        Some(ids) => {
            for (&i, &a) in ids.iter().zip(answers.iter()) {
                keep(i as usize, a);
            }
        }
    }
}

/// Mean-square error of the pairs after moving the scan to `pose`.
fn registered_mse(scan: &[[f64; 2]], map: &[[f64; 2]], pairs: &[Pair], pose: Pose2) -> f64 {
    let (s, c) = pose.theta.sin_cos();
    let mut sum = 0.0;
    for pr in pairs {
        let p = scan[pr.i as usize];
        let x = map[pr.j as usize];
        let dx = pose.x + c * p[0] - s * p[1] - x[0];
        let dy = pose.y + s * p[0] + c * p[1] - x[1];
        sum += dx * dx + dy * dy;
    }
    sum / pairs.len().max(1) as f64
}

/// Besl & McKay's accelerated ICP (their §IV-C): when the last registration steps point the
/// same way in (x, y, L·θ) space, jump ahead along the step to where a line or parabola
/// fitted to the last three errors says the error is least, at most 25 steps.
struct Accelerator {
    /// radius of gyration of the scan: the length that makes θ comparable to x, y
    scale: f64,
    hist: Vec<(Pose2, f64)>,
}

impl Accelerator {
    fn new(scan: &[[f64; 2]]) -> Self {
        let n = scan.len().max(1) as f64;
        let (mx, my) = scan
            .iter()
            .fold((0.0, 0.0), |a, p| (a.0 + p[0] / n, a.1 + p[1] / n));
        let r2 = scan
            .iter()
            .map(|p| (p[0] - mx).powi(2) + (p[1] - my).powi(2))
            .sum::<f64>()
            / n;
        Self {
            scale: r2.sqrt().max(1e-3),
            hist: Vec::with_capacity(3),
        }
    }

    fn reset(&mut self) {
        self.hist.clear();
    }

    fn vec(&self, a: &Pose2, b: &Pose2) -> [f64; 3] {
        [
            b.x - a.x,
            b.y - a.y,
            self.scale * wrap_angle(b.theta - a.theta),
        ]
    }

    /// Record the registered pose and its error; maybe return an extrapolated pose.
    fn step(&mut self, pose: Pose2, err: f64) -> Pose2 {
        if !err.is_finite() {
            self.reset();
            return pose;
        }
        self.hist.push((pose, err));
        if self.hist.len() > 3 {
            self.hist.remove(0);
        }
        if self.hist.len() < 3 {
            return pose;
        }
        let (q0, e0) = self.hist[0];
        let (q1, e1) = self.hist[1];
        let (q2, e2) = self.hist[2];
        let d1 = self.vec(&q0, &q1);
        let d2 = self.vec(&q1, &q2);
        let n1 = (d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]).sqrt();
        let n2 = (d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2]).sqrt();
        if n1 < 1e-12 || n2 < 1e-12 {
            return pose;
        }
        let cos = (d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]) / (n1 * n2);
        if cos < 10f64.to_radians().cos() {
            return pose;
        }
        // errors at arc positions v = -(n1 + n2), -n2, 0
        let v = [-(n1 + n2), -n2, 0.0];
        let e = [e0, e1, e2];
        let vmax = 25.0 * n2;
        // line by least squares: e = a v + b; zero crossing -b/a
        let vm = (v[0] + v[1] + v[2]) / 3.0;
        let em = (e[0] + e[1] + e[2]) / 3.0;
        let sxy: f64 = (0..3).map(|i| (v[i] - vm) * (e[i] - em)).sum();
        let sxx: f64 = (0..3).map(|i| (v[i] - vm) * (v[i] - vm)).sum();
        let a = sxy / sxx;
        let b = em - a * vm;
        let v_lin = if a < 0.0 { -b / a } else { f64::NAN };
        // parabola through the three points: vertex
        let (x0, x1, x2) = (v[0], v[1], v[2]);
        let den = (x0 - x1) * (x0 - x2) * (x1 - x2);
        let pa = (x2 * (e1 - e0) + x1 * (e0 - e2) + x0 * (e2 - e1)) / den;
        let pb = (x2 * x2 * (e0 - e1) + x1 * x1 * (e2 - e0) + x0 * x0 * (e1 - e2)) / den;
        let v_par = if pa > 0.0 { -pb / (2.0 * pa) } else { f64::NAN };
        let ok = |x: f64| x.is_finite() && x > 0.0;
        let jump = if ok(v_par) && ok(v_lin) && v_par < v_lin {
            v_par.min(vmax)
        } else if ok(v_lin) {
            v_lin.min(vmax)
        } else if ok(v_par) {
            v_par.min(vmax)
        } else {
            return pose;
        };
        let f = jump / n2;
        self.reset();
        Pose2::new(
            pose.x + f * d2[0],
            pose.y + f * d2[1],
            wrap_angle(pose.theta + f * d2[2] / self.scale),
        )
    }
}

/// The start search stops at the start pose itself, or after the start position's
/// headings, when the best fit so far has this fraction of the subsampled scan within
/// `min_correspondence_distance` (a scan with more clutter than that simply gets the full
/// search). Measured on the peer scenario
/// (20 % of beams on unmapped obstacles): 0.75 keeps 99–100 % success at a quarter of the
/// cost of always searching the 3 × 3 positions.
const SEARCH_GOOD_FIT: f64 = 0.75;

/// Try initial headings around `start`; return the start pose of the best short coarse ICP.
fn heading_search(
    scan: &[[f64; 2]],
    index: &MapIndex,
    start: Pose2,
    cfg: &IcpConfig,
    ws: &mut Workspace,
) -> Pose2 {
    let stride = (scan.len() / 60).max(1);
    let sub: Vec<[f64; 2]> = scan.iter().step_by(stride).copied().collect();
    if sub.len() < 3 {
        return start;
    }
    let coarse = IcpConfig {
        max_iterations: 4,
        min_correspondence_distance: (cfg.max_correspondence_distance * 0.25)
            .max(cfg.min_correspondence_distance),
        heading_search: 0.0,
        position_search: 0.0,
        min_inliers: 3,
        min_inlier_ratio: 0.0,
        trim_fraction: 1.0,
        ..cfg.clone()
    };
    let score_d2 = {
        let d = cfg.min_correspondence_distance.max(0.05);
        d * d
    };
    // candidates in order of distance from the start (the start first), so that ties keep
    // the start: strict improvement only
    let line_normals = if cfg.metric == Metric::PointToLine {
        Some(index.normals())
    } else {
        None
    };
    let k = (cfg.heading_search / cfg.heading_step).round() as i64;
    let headings: Vec<i64> = std::iter::once(0)
        .chain((1..=k).flat_map(|h| [-h, h]))
        .collect();
    let r = cfg.position_search;
    let offsets: &[(f64, f64)] = if r > 0.0 {
        &[
            (0.0, 0.0),
            (-1.0, 0.0),
            (1.0, 0.0),
            (0.0, -1.0),
            (0.0, 1.0),
            (-1.0, -1.0),
            (1.0, -1.0),
            (-1.0, 1.0),
            (1.0, 1.0),
        ]
    } else {
        &[(0.0, 0.0)]
    };
    let mut best = (0usize, f64::INFINITY, start);
    for (oi, &(ox, oy)) in offsets.iter().enumerate() {
        // the start position with every heading first; the offset positions only when
        // none of those explains most of the scan
        if oi == 1 && best.0 as f64 >= SEARCH_GOOD_FIT * sub.len() as f64 {
            break;
        }
        for &h in &headings {
            let p0 = Pose2::new(
                start.x + ox * r,
                start.y + oy * r,
                wrap_angle(start.theta + h as f64 * cfg.heading_step),
            );
            let r = align_plain(&sub, index, p0, &coarse, ws);
            let (s, c) = r.pose.theta.sin_cos();
            let mut hits = 0usize;
            let mut sum = 0.0;
            for p in &sub {
                let q = [
                    r.pose.x + c * p[0] - s * p[1],
                    r.pose.y + s * p[0] + c * p[1],
                ];
                let (mut d2, j) = index.correspondence(q);
                if let Some(nrm) = line_normals {
                    // point-to-line: score the distance to the wall, not to its nearest sample
                    // (on a sparsely sampled map the latter is large even when aligned)
                    if d2 <= 4.0 * score_d2 {
                        let (x, n) = (index.points()[j], nrm[j]);
                        let e = n[0] * (q[0] - x[0]) + n[1] * (q[1] - x[1]);
                        d2 = e * e;
                    }
                }
                if d2 <= score_d2 {
                    hits += 1;
                    sum += d2;
                }
            }
            let mse = if hits > 0 {
                sum / hits as f64
            } else {
                f64::INFINITY
            };
            if hits > best.0 || (hits == best.0 && mse < best.1) {
                best = (hits, mse, r.pose);
            }
            // the start itself already explains most of the scan: nothing to search for
            if oi == 0 && h == 0 && best.0 as f64 >= SEARCH_GOOD_FIT * sub.len() as f64 {
                return best.2;
            }
        }
    }
    best.2
}

/// One damped Gauss–Newton step of the point-to-line cost; the translation is capped at
/// the current threshold and the rotation at 0.5 rad (a step farther than any pair's
/// distance cannot be trusted).
fn solve_step(h: &Matrix3<f64>, g: &Vector3<f64>, thr: f64) -> [f64; 3] {
    // damping relative to each diagonal term (Marquardt): a trace-scaled one is dominated
    // by the rotation's term (r² per pair) and, with the scan far from the map (70 m),
    // damps the translation so hard that the stop on a small step comes 1e-9 m early
    let mut hd = *h;
    for k in 0..3 {
        hd[(k, k)] += 1e-9 * h[(k, k)] + 1e-12;
    }
    let step = match hd.cholesky() {
        Some(ch) => ch.solve(&(-g)),
        None => {
            let eig = SymmetricEigen::new(hd);
            let mut inv = Matrix3::zeros();
            let lmax = eig.eigenvalues.max().max(1e-300);
            for k in 0..3 {
                let l = eig.eigenvalues[k];
                if l > 1e-12 * lmax {
                    let v = eig.eigenvectors.column(k);
                    inv += v * v.transpose() / l;
                }
            }
            inv * (-g)
        }
    };
    let mut s = [step[0], step[1], step[2]];
    if !(s[0].is_finite() && s[1].is_finite() && s[2].is_finite()) {
        return [0.0; 3];
    }
    let t = (s[0] * s[0] + s[1] * s[1]).sqrt();
    if t > thr {
        s[0] *= thr / t;
        s[1] *= thr / t;
    }
    s[2] = s[2].clamp(-0.5, 0.5);
    s
}

type Uncertainty = ([[f64; 3]; 3], [[f64; 3]; 3], f64, [f64; 2]);

/// Information, covariance and degeneracy of the point-to-line cost at `pose` over the
/// final pairs (the pairs' map points and normals; scan points moved to `pose`).
fn uncertainty(
    scan: &[[f64; 2]],
    index: &MapIndex,
    pose: Pose2,
    pairs: &[Pair],
    _cfg: &IcpConfig,
) -> Uncertainty {
    let nrm = index.normals();
    let map = index.points();
    let (s, c) = pose.theta.sin_cos();
    let mut h = Matrix3::<f64>::zeros();
    let mut sum = 0.0;
    for pr in pairs {
        let p = scan[pr.i as usize];
        let dq = [c * p[0] - s * p[1], s * p[0] + c * p[1]];
        let q = [pose.x + dq[0], pose.y + dq[1]];
        let x = map[pr.j as usize];
        let nv = nrm[pr.j as usize];
        let r = nv[0] * (q[0] - x[0]) + nv[1] * (q[1] - x[1]);
        let jac = Vector3::new(nv[0], nv[1], nv[1] * dq[0] - nv[0] * dq[1]);
        h += jac * jac.transpose();
        sum += r * r;
    }
    let m = pairs.len();
    let sigma2 = if m > 3 {
        (sum / (m - 3) as f64).max(1e-12)
    } else {
        f64::INFINITY
    };
    // covariance = σ² H⁻¹, with unobservable directions given a huge (finite) variance
    let eig = SymmetricEigen::new(h);
    let lmax = eig.eigenvalues.max();
    let mut cov = Matrix3::<f64>::zeros();
    for k in 0..3 {
        let l = eig.eigenvalues[k];
        let v = eig.eigenvectors.column(k);
        let inv = if lmax > 0.0 && l > 1e-9 * lmax {
            1.0 / l
        } else {
            1e12
        };
        cov += v * v.transpose() * inv;
    }
    if sigma2.is_finite() {
        cov *= sigma2;
    } else {
        cov = Matrix3::identity() * 1e12;
    }
    // degeneracy of the translational block
    let ht = Matrix2::new(h[(0, 0)], h[(0, 1)], h[(1, 0)], h[(1, 1)]);
    let e2 = SymmetricEigen::new(ht);
    let (imin, imax) = if e2.eigenvalues[0] <= e2.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    let lmin = e2.eigenvalues[imin].max(0.0);
    let lmx = e2.eigenvalues[imax];
    let degeneracy = if lmx > 0.0 {
        (lmin / lmx).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let v = e2.eigenvectors.column(imin);
    let mut dir = [v[0], v[1]];
    if dir[0] < 0.0 || (dir[0] == 0.0 && dir[1] < 0.0) {
        dir = [-dir[0], -dir[1]];
    }
    let to_arr = |a: &Matrix3<f64>| {
        let mut o = [[0.0; 3]; 3];
        for (r, row) in o.iter_mut().enumerate() {
            for (k, v) in row.iter_mut().enumerate() {
                *v = a[(r, k)];
            }
        }
        o
    };
    (to_arr(&h), to_arr(&cov), degeneracy, dir)
}

#[cfg(test)]
mod tests;
