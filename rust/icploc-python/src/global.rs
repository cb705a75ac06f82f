//! `icploc._core.GlobalLocalizer`: the global search of `icploc_core::global`, GIL
//! released around every heavy call.

use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use icploc_core::global::{Candidate, GlobalConfig, GlobalLocalizer, GlobalResult};
use icploc_core::Pose2;

use crate::{array2, guarded, input_err, to_py, PyIcpConfig, PyMapIndex};

/// One ranked pose hypothesis of a global search.
#[pyclass(name = "GlobalCandidate", module = "icploc._core", frozen)]
#[derive(Clone)]
pub struct PyCandidate {
    inner: Candidate,
}

#[pymethods]
impl PyCandidate {
    #[getter]
    fn pose(&self) -> (f64, f64, f64) {
        let p = self.inner.pose;
        (p.x, p.y, p.theta)
    }
    #[getter]
    fn score(&self) -> f64 {
        self.inner.score
    }
    #[getter]
    fn inlier_ratio(&self) -> f64 {
        self.inner.inlier_ratio
    }
    #[getter]
    fn mse(&self) -> f64 {
        self.inner.mse
    }
    #[getter]
    fn see_through(&self) -> f64 {
        self.inner.see_through
    }
    #[getter]
    fn coarse_score(&self) -> f64 {
        self.inner.coarse_score
    }

    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        d.set_item("pose", self.pose())?;
        d.set_item("score", self.inner.score)?;
        d.set_item("inlier_ratio", self.inner.inlier_ratio)?;
        d.set_item("mse", self.inner.mse)?;
        d.set_item("see_through", self.inner.see_through)?;
        d.set_item("coarse_score", self.inner.coarse_score)?;
        Ok(d)
    }

    fn __repr__(&self) -> String {
        let p = self.inner.pose;
        format!(
            "GlobalCandidate(pose=({:.4}, {:.4}, {:.4}), score={:.4}, inlier_ratio={:.3}, mse={:.3e}, see_through={:.3})",
            p.x, p.y, p.theta, self.inner.score, self.inner.inlier_ratio, self.inner.mse, self.inner.see_through
        )
    }
}

/// The outcome of one global search.
#[pyclass(name = "GlobalSearchResult", module = "icploc._core", frozen)]
pub struct PyGlobalResult {
    inner: GlobalResult,
}

#[pymethods]
impl PyGlobalResult {
    #[getter]
    fn candidates(&self) -> Vec<PyCandidate> {
        self.inner
            .candidates
            .iter()
            .map(|c| PyCandidate { inner: c.clone() })
            .collect()
    }
    #[getter]
    fn best(&self) -> Option<PyCandidate> {
        self.inner.best().map(|c| PyCandidate { inner: c.clone() })
    }
    #[getter]
    fn ambiguous(&self) -> bool {
        self.inner.ambiguous
    }
    /// Quadtree nodes scored below the level a large region's search starts from (see
    /// `dense_nodes`).
    #[getter]
    fn nodes(&self) -> usize {
        self.inner.nodes
    }
    /// Nodes of the start level of a large region's search, summed densely; 0 for a search
    /// from the top level.
    #[getter]
    fn dense_nodes(&self) -> usize {
        self.inner.dense_nodes
    }
    #[getter]
    fn leaves(&self) -> usize {
        self.inner.leaves
    }
    #[getter]
    fn headings(&self) -> usize {
        self.inner.headings
    }
    #[getter]
    fn coarse_time(&self) -> f64 {
        self.inner.coarse_time
    }
    #[getter]
    fn refine_time(&self) -> f64 {
        self.inner.refine_time
    }
    fn __len__(&self) -> usize {
        self.inner.candidates.len()
    }
    fn __repr__(&self) -> String {
        format!(
            "GlobalSearchResult({} candidates, ambiguous={}, best={})",
            self.inner.candidates.len(),
            if self.inner.ambiguous {
                "True"
            } else {
                "False"
            },
            self.best()
                .map(|c| c.__repr__())
                .unwrap_or_else(|| "None".into())
        )
    }
}

/// Global localization against one map: a likelihood pyramid built once, then
/// branch-and-bound searches over positions and headings with ICP refinement.
#[pyclass(name = "GlobalLocalizer", module = "icploc._core", frozen)]
pub struct PyGlobalLocalizer {
    inner: GlobalLocalizer,
    index: Py<PyMapIndex>,
}

fn poses_arg(py: Python<'_>, obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<Pose2>> {
    let a = array2(py, obj, 3, what)?;
    Ok(a.flat()
        .chunks_exact(3)
        .map(|c| Pose2::new(c[0], c[1], c[2]))
        .collect())
}

fn pair4(py: Python<'_>, obj: Option<&Bound<'_, PyAny>>, what: &str) -> PyResult<Option<[f64; 4]>> {
    match obj {
        None => Ok(None),
        Some(o) if o.is_none() => Ok(None),
        Some(o) => {
            let v: Vec<f64> = o.extract().map_err(|_| {
                input_err(
                    py,
                    what,
                    "expected 4 numbers (xmin, ymin, xmax, ymax)".into(),
                )
            })?;
            if v.len() != 4 {
                return Err(input_err(
                    py,
                    what,
                    format!("expected 4 numbers, got {}", v.len()),
                ));
            }
            Ok(Some([v[0], v[1], v[2], v[3]]))
        }
    }
}

#[pymethods]
impl PyGlobalLocalizer {
    #[new]
    /// Every setting left `None` is the core's default (`GlobalConfig::default()`, see
    /// `global_defaults()`): the one source.
    #[pyo3(signature = (
        index, resolution=0.05, *, angle_step=None, max_points=None, sigma=None,
        min_clearance=None, accept_ratio=None, min_score=None, max_candidates=None,
        levels=None, score_sigma=None, inlier_distance=None, distinct_distance=None,
        distinct_angle=None, ambiguity_margin=None, icp_config=None, distances=None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        index: Bound<'_, PyMapIndex>,
        resolution: f64,
        angle_step: Option<f64>,
        max_points: Option<usize>,
        sigma: Option<f64>,
        min_clearance: Option<f64>,
        accept_ratio: Option<f64>,
        min_score: Option<f64>,
        max_candidates: Option<usize>,
        levels: Option<usize>,
        score_sigma: Option<f64>,
        inlier_distance: Option<f64>,
        distinct_distance: Option<f64>,
        distinct_angle: Option<f64>,
        ambiguity_margin: Option<f64>,
        icp_config: Option<PyRef<'_, PyIcpConfig>>,
        distances: Option<PyReadonlyArray1<'_, f32>>,
    ) -> PyResult<Self> {
        let d = GlobalConfig::default();
        let icp = match icp_config {
            Some(c) => c.to_core().map_err(|e| to_py(py, e))?,
            None => d.icp.clone(),
        };
        let cfg = GlobalConfig {
            angle_step: angle_step.unwrap_or(d.angle_step),
            max_points: max_points.unwrap_or(d.max_points),
            sigma: sigma.unwrap_or(d.sigma),
            min_clearance: min_clearance.unwrap_or(d.min_clearance),
            accept_ratio: accept_ratio.unwrap_or(d.accept_ratio),
            min_score: min_score.unwrap_or(d.min_score),
            max_candidates: max_candidates.unwrap_or(d.max_candidates),
            levels: levels.unwrap_or(d.levels),
            score_sigma: score_sigma.unwrap_or(d.score_sigma),
            inlier_distance: inlier_distance.unwrap_or(d.inlier_distance),
            distinct_distance: distinct_distance.unwrap_or(d.distinct_distance),
            distinct_angle: distinct_angle.unwrap_or(d.distinct_angle),
            ambiguity_margin: ambiguity_margin.unwrap_or(d.ambiguity_margin),
            icp,
            ..d
        };
        let idx = index.get().inner.clone();
        // the field's distances of an earlier build on this map (a cache): no k-d tree queries
        let dist = match &distances {
            Some(d) => Some(
                d.as_slice()
                    .map_err(|_| input_err(py, "distances", "must be contiguous float32".into()))?
                    .to_vec(),
            ),
            None => None,
        };
        let inner = py
            .detach(|| {
                guarded(|| match dist {
                    Some(d) => GlobalLocalizer::from_distances(idx, resolution, cfg, d),
                    None => GlobalLocalizer::new(idx, resolution, cfg),
                })
            })
            .map_err(|e| to_py(py, e))?;
        Ok(Self {
            inner,
            index: index.unbind(),
        })
    }

    /// Search for the pose of `scan_xy` (N, 2 sensor-frame points); `region`: the sensor
    /// position's (xmin, ymin, xmax, ymax), `heading`: (min, max) radians.
    /// `min_score`: this search's coarse floor in place of the configured one.
    #[pyo3(signature = (scan_xy, region=None, heading=None, min_score=None))]
    fn search(
        &self,
        py: Python<'_>,
        scan_xy: &Bound<'_, PyAny>,
        region: Option<&Bound<'_, PyAny>>,
        heading: Option<(f64, f64)>,
        min_score: Option<f64>,
    ) -> PyResult<PyGlobalResult> {
        let scan = array2(py, scan_xy, 2, "scan_xy")?;
        let region = pair4(py, region, "region")?;
        let s = scan.pairs();
        let r = py
            .detach(|| guarded(|| self.inner.search_above(s, region, heading, min_score)))
            .map_err(|e| to_py(py, e))?;
        Ok(PyGlobalResult { inner: r })
    }

    /// Refine each (M, 3) pose by ICP and score it like a search candidate.
    fn refine(
        &self,
        py: Python<'_>,
        scan_xy: &Bound<'_, PyAny>,
        poses: &Bound<'_, PyAny>,
    ) -> PyResult<Vec<PyCandidate>> {
        self.at_poses(py, scan_xy, poses, GlobalLocalizer::refine)
    }

    /// Score `scan_xy` at each (M, 3) pose without refinement.
    fn score(
        &self,
        py: Python<'_>,
        scan_xy: &Bound<'_, PyAny>,
        poses: &Bound<'_, PyAny>,
    ) -> PyResult<Vec<PyCandidate>> {
        self.at_poses(py, scan_xy, poses, GlobalLocalizer::score)
    }

    /// Are two poses distinct hypotheses (farther apart than distinct_distance or
    /// distinct_angle)?
    fn distinct(&self, a: (f64, f64, f64), b: (f64, f64, f64)) -> bool {
        self.inner
            .distinct(&Pose2::new(a.0, a.1, a.2), &Pose2::new(b.0, b.1, b.2))
    }

    /// Distance (m) from each (N, 2) point to the map, from the grid (nan outside it).
    fn distance<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let pts = array2(py, points, 2, "points")?;
        let v: Vec<f64> = pts
            .pairs()
            .iter()
            .map(|p| self.inner.distance_at(*p).unwrap_or(f64::NAN))
            .collect();
        Ok(PyArray1::from_vec(py, v))
    }

    /// The likelihood field's distances (m, each cell centre to the map, row by row;
    /// float32): what `distances=` takes to rebuild this localizer without recomputing them.
    fn distances<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        PyArray1::from_slice(py, self.inner.distances())
    }

    #[getter]
    fn index(&self, py: Python<'_>) -> Py<PyMapIndex> {
        self.index.clone_ref(py)
    }
    #[getter]
    fn resolution(&self) -> f64 {
        self.inner.resolution()
    }
    #[getter]
    fn shape(&self) -> (usize, usize) {
        self.inner.shape()
    }
    #[getter]
    fn free_cells(&self) -> usize {
        self.inner.free_cells()
    }
    #[getter]
    fn angle_step(&self) -> f64 {
        self.inner.config().angle_step
    }
    #[getter]
    fn ambiguity_margin(&self) -> f64 {
        self.inner.config().ambiguity_margin
    }
    #[getter]
    fn distinct_distance(&self) -> f64 {
        self.inner.config().distinct_distance
    }
    #[getter]
    fn distinct_angle(&self) -> f64 {
        self.inner.config().distinct_angle
    }

    fn __repr__(&self) -> String {
        let (w, h) = self.inner.shape();
        format!(
            "GlobalLocalizer(resolution={}, cells={}x{}, free_cells={})",
            self.inner.resolution(),
            w,
            h,
            self.inner.free_cells()
        )
    }
}

/// `GlobalLocalizer::refine` or `GlobalLocalizer::score`.
type AtPoses = fn(&GlobalLocalizer, &[[f64; 2]], &[Pose2]) -> icploc_core::Result<Vec<Candidate>>;

impl PyGlobalLocalizer {
    /// `op` (refine or score) of one scan at each of the (M, 3) poses, GIL released.
    fn at_poses(
        &self,
        py: Python<'_>,
        scan_xy: &Bound<'_, PyAny>,
        poses: &Bound<'_, PyAny>,
        op: AtPoses,
    ) -> PyResult<Vec<PyCandidate>> {
        let scan = array2(py, scan_xy, 2, "scan_xy")?;
        let poses = poses_arg(py, poses, "poses")?;
        let s = scan.pairs();
        let r = py
            .detach(|| guarded(|| op(&self.inner, s, &poses)))
            .map_err(|e| to_py(py, e))?;
        Ok(r.into_iter().map(|inner| PyCandidate { inner }).collect())
    }
}

/// The core's defaults of the global search settings `GlobalLocalizer` takes (metres,
/// radians): `GlobalConfig::default()`, the one source of them.
#[pyfunction]
fn global_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = GlobalConfig::default();
    let out = PyDict::new(py);
    out.set_item("angle_step", d.angle_step)?;
    out.set_item("max_points", d.max_points)?;
    out.set_item("sigma", d.sigma)?;
    out.set_item("min_clearance", d.min_clearance)?;
    out.set_item("accept_ratio", d.accept_ratio)?;
    out.set_item("min_score", d.min_score)?;
    out.set_item("max_candidates", d.max_candidates)?;
    out.set_item("levels", d.levels)?;
    out.set_item("score_sigma", d.score_sigma)?;
    out.set_item("inlier_distance", d.inlier_distance)?;
    out.set_item("distinct_distance", d.distinct_distance)?;
    out.set_item("distinct_angle", d.distinct_angle)?;
    out.set_item("ambiguity_margin", d.ambiguity_margin)?;
    Ok(out)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("FIELD_VERSION", icploc_core::likelihood::FIELD_VERSION)?;
    m.add_function(wrap_pyfunction!(global_defaults, m)?)?;
    m.add_class::<PyGlobalLocalizer>()?;
    m.add_class::<PyGlobalResult>()?;
    m.add_class::<PyCandidate>()?;
    Ok(())
}
