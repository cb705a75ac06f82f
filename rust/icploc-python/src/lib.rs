//! pyo3 bindings for `icploc-core`: the private module `icploc._core`.
//!
//! Thin wrappers only: array arguments are borrowed from numpy without copying when they
//! are C-contiguous float64 (converted otherwise), the GIL is released around every heavy
//! call, core errors become Python exceptions, and a panic in the core (a bug) surfaces as
//! `IcpError`, never as a crash.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;

use numpy::ndarray::Array2;
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

use icploc_core as core;
use icploc_core::{IcpError as CoreError, Pose2};

mod global;
mod gridstore;
mod maps;
mod perscan;

static ICP_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static INVALID_INPUT: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static EMPTY_MAP: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static INVALID_CONFIG: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static GRID_TOO_LARGE: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// A class with several bases (e.g. IcpError and ValueError), made with `type()`.
fn make_class(
    py: Python<'_>,
    name: &str,
    bases: Vec<Bound<'_, PyType>>,
    doc: &str,
) -> PyResult<Py<PyType>> {
    let dict = PyDict::new(py);
    dict.set_item("__module__", "icploc._core")?;
    dict.set_item("__doc__", doc)?;
    let bases = PyTuple::new(py, bases)?;
    let cls = py.get_type::<PyType>().call1((name, bases, dict))?;
    Ok(cls.cast_into::<PyType>()?.unbind())
}

/// `IcpError`, the base of the core's errors: under `icploc.errors.IcplocError`, the one
/// error root of the package (a plain `Exception` if that module cannot be imported).
fn icp_error(py: Python<'_>) -> &Py<PyType> {
    ICP_ERROR.get_or_init(py, || {
        let root = py
            .import("icploc.errors")
            .and_then(|m| m.getattr("IcplocError"))
            .and_then(|c| Ok(c.cast_into::<PyType>()?))
            .unwrap_or_else(|_| py.get_type::<PyException>());
        make_class(
            py,
            "IcpError",
            vec![root],
            "Base class of every error raised by the ICP core.",
        )
        .expect("creating IcpError")
    })
}

fn invalid_input(py: Python<'_>) -> &Py<PyType> {
    INVALID_INPUT.get_or_init(py, || {
        make_class(
            py,
            "InvalidInputError",
            vec![
                icp_error(py).bind(py).clone(),
                py.get_type::<PyValueError>(),
            ],
            "An input array has the wrong shape or dtype, holds NaN/inf, or has too few points.",
        )
        .expect("creating InvalidInputError")
    })
}

fn empty_map(py: Python<'_>) -> &Py<PyType> {
    EMPTY_MAP.get_or_init(py, || {
        let base = invalid_input(py).bind(py).clone();
        make_class(py, "EmptyMapError", vec![base], "The map has no points.")
            .expect("creating EmptyMapError")
    })
}

fn grid_too_large(py: Python<'_>) -> &Py<PyType> {
    GRID_TOO_LARGE.get_or_init(py, || {
        let base = invalid_input(py).bind(py).clone();
        make_class(
            py,
            "GridTooLargeError",
            vec![base],
            "A grid would need more cells than the core's memory bound (use a coarser resolution).",
        )
        .expect("creating GridTooLargeError")
    })
}

fn invalid_config(py: Python<'_>) -> &Py<PyType> {
    INVALID_CONFIG.get_or_init(py, || {
        make_class(
            py,
            "InvalidConfigError",
            vec![
                icp_error(py).bind(py).clone(),
                py.get_type::<PyValueError>(),
            ],
            "A configuration value is out of range (e.g. a non-positive threshold).",
        )
        .expect("creating InvalidConfigError")
    })
}

/// Core error → Python exception of the matching class.
fn to_py(py: Python<'_>, e: CoreError) -> PyErr {
    let msg = e.to_string();
    let cls = match e {
        CoreError::EmptyMap => empty_map(py),
        CoreError::GridTooLarge { .. } => grid_too_large(py),
        CoreError::InvalidConfig { .. } => invalid_config(py),
        CoreError::Internal(_) => icp_error(py),
        _ => invalid_input(py),
    };
    PyErr::from_type(cls.bind(py).clone(), msg)
}

fn input_err(py: Python<'_>, what: &str, reason: String) -> PyErr {
    to_py(
        py,
        CoreError::InvalidInput {
            what: what.to_string(),
            reason,
        },
    )
}

/// Run a core call with a panic guard (a panic is a bug: report it, don't crash).
fn guarded<T>(f: impl FnOnce() -> core::Result<T>) -> core::Result<T> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(p) => {
            let msg = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(CoreError::Internal(format!("panic in the core: {msg}")))
        }
    }
}

/// An (N, K) float64 array: borrowed from numpy when C-contiguous float64, else converted.
enum Array<'py> {
    Borrowed(PyReadonlyArray2<'py, f64>),
    Owned(Vec<f64>),
}

impl Array<'_> {
    fn flat(&self) -> &[f64] {
        match self {
            Array::Borrowed(a) => a.as_slice().expect("checked contiguous"),
            Array::Owned(v) => v,
        }
    }
    fn pairs(&self) -> &[[f64; 2]] {
        let f = self.flat();
        // SAFETY: [f64; 2] has the size of two f64 and the alignment of one; the flat
        // slice of an (N, 2) C-contiguous array holds N such pairs back to back.
        unsafe { std::slice::from_raw_parts(f.as_ptr() as *const [f64; 2], f.len() / 2) }
    }
}

fn array2<'py>(
    py: Python<'py>,
    obj: &Bound<'py, PyAny>,
    cols: usize,
    what: &str,
) -> PyResult<Array<'py>> {
    let shape_err = |shape: &[usize]| {
        to_py(
            py,
            CoreError::Shape {
                what: what.to_string(),
                expected: format!("an (N, {cols}) array"),
                got: format!("shape {shape:?}"),
            },
        )
    };
    if let Ok(a) = obj.extract::<PyReadonlyArray2<'py, f64>>() {
        if a.shape()[1] != cols {
            return Err(shape_err(a.shape()));
        }
        // Borrow only C-order data: `as_slice` also accepts Fortran order, whose flat
        // layout is column after column.
        if a.is_c_contiguous() && a.as_slice().is_ok() {
            return Ok(Array::Borrowed(a));
        }
        return Ok(Array::Owned(a.as_array().iter().copied().collect()));
    }
    // Not a float64 2-D array: let numpy convert it (lists, ints, float32, ...).
    let np = py.import("numpy")?;
    let conv = np
        .call_method1("ascontiguousarray", (obj,))
        .and_then(|a| a.call_method1("astype", ("float64",)))
        .map_err(|e| input_err(py, what, format!("cannot convert to a float64 array: {e}")))?;
    let shape: Vec<usize> = conv.getattr("shape")?.extract()?;
    if shape.len() != 2 || shape[1] != cols {
        return Err(shape_err(&shape));
    }
    let a: PyReadonlyArray2<'py, f64> = conv.extract()?;
    Ok(Array::Owned(a.as_array().iter().copied().collect()))
}

fn vector<'py>(py: Python<'py>, obj: &Bound<'py, PyAny>, what: &str) -> PyResult<Vec<f64>> {
    if let Ok(a) = obj.extract::<PyReadonlyArray1<'py, f64>>() {
        return Ok(a.as_array().to_vec());
    }
    let np = py.import("numpy")?;
    let conv = np
        .call_method1("asarray", (obj,))
        .and_then(|a| a.call_method1("astype", ("float64",)))
        .map_err(|e| input_err(py, what, format!("cannot convert to a float64 array: {e}")))?;
    let shape: Vec<usize> = conv.getattr("shape")?.extract()?;
    if shape.len() != 1 {
        return Err(to_py(
            py,
            CoreError::Shape {
                what: what.into(),
                expected: "a 1-D array".into(),
                got: format!("shape {shape:?}"),
            },
        ));
    }
    let a: PyReadonlyArray1<'py, f64> = conv.extract()?;
    Ok(a.as_array().to_vec())
}

fn pose_arg<'py>(py: Python<'py>, obj: &Bound<'py, PyAny>, what: &str) -> PyResult<Pose2> {
    let v = vector(py, obj, what)?;
    if v.len() != 3 {
        return Err(to_py(
            py,
            CoreError::Shape {
                what: what.into(),
                expected: "3 values (x, y, theta)".into(),
                got: format!("{} values", v.len()),
            },
        ));
    }
    Ok(Pose2::new(v[0], v[1], v[2]))
}

/// A pose argument: a tuple of three floats as it is (the localizer's poses; no numpy
/// conversion), anything else as [`pose_arg`] reads it.
pub(crate) fn pose_fast<'py>(
    py: Python<'py>,
    obj: &Bound<'py, PyAny>,
    what: &str,
) -> PyResult<Pose2> {
    if let Ok((x, y, t)) = obj.extract::<(f64, f64, f64)>() {
        return Ok(Pose2::new(x, y, t));
    }
    pose_arg(py, obj, what)
}

fn mat3<'py>(py: Python<'py>, m: &[[f64; 3]; 3]) -> Bound<'py, PyArray2<f64>> {
    let v: Vec<f64> = m.iter().flatten().copied().collect();
    Array2::from_shape_vec((3, 3), v)
        .expect("3x3")
        .into_pyarray(py)
}

// ---------------------------------------------------------------- MapIndex

/// (distances, indices) of `MapIndex.nearest`.
type Nearest<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<i64>>);

/// An immutable k-d tree over 2D map points with optional unit normals.
#[pyclass(name = "MapIndex", module = "icploc._core", frozen)]
struct PyMapIndex {
    inner: Arc<core::MapIndex>,
}

#[pymethods]
impl PyMapIndex {
    #[new]
    #[pyo3(signature = (points, normals=None, cache_resolution=Some(0.02)))]
    fn new(
        py: Python<'_>,
        points: &Bound<'_, PyAny>,
        normals: Option<&Bound<'_, PyAny>>,
        cache_resolution: Option<f64>,
    ) -> PyResult<Self> {
        let p = array2(py, points, 2, "map points")?;
        let n = match normals {
            Some(n) if !n.is_none() => Some(array2(py, n, 2, "map normals")?),
            _ => None,
        };
        let pv = p.pairs().to_vec();
        let nv = n.as_ref().map(|a| a.pairs().to_vec());
        let idx = py
            .detach(|| guarded(|| core::MapIndex::new(pv, nv)?.with_cache(cache_resolution)))
            .map_err(|e| to_py(py, e))?;
        Ok(Self {
            inner: Arc::new(idx),
        })
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __repr__(&self) -> String {
        let b = self.inner.bounds();
        format!(
            "MapIndex({} points, normals={}, cache_resolution={:?}, bounds=({:.3}, {:.3}, {:.3}, {:.3}))",
            self.inner.len(),
            if self.inner.has_normals() { "given" } else { "estimated" },
            self.inner.cache_resolution(),
            b[0],
            b[1],
            b[2],
            b[3]
        )
    }

    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        pairs_to_array(py, self.inner.points())
    }

    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let inner = self.inner.clone();
        py.detach(move || {
            inner.normals();
        });
        pairs_to_array(py, self.inner.normals())
    }

    #[getter]
    fn has_normals(&self) -> bool {
        self.inner.has_normals()
    }

    #[getter]
    fn bounds(&self) -> (f64, f64, f64, f64) {
        let b = self.inner.bounds();
        (b[0], b[1], b[2], b[3])
    }

    /// Cell size of the closest-point grid used by ICP (None: exact k-d tree answers).
    #[getter]
    fn cache_resolution(&self) -> Option<f64> {
        self.inner.cache_resolution()
    }

    /// Why the requested closest-point grid was not built (None when it was, or when none
    /// was asked for); ICP then gets exact, slower, k-d tree answers.
    #[getter]
    fn cache_fallback(&self) -> Option<String> {
        self.inner.cache_fallback().map(str::to_owned)
    }

    /// Heap bytes held by the closest-point grid (0 without one).
    #[getter]
    fn cache_bytes(&self) -> usize {
        self.inner.cache_bytes()
    }

    /// Median nearest-neighbour spacing of the map points (m).
    #[getter]
    fn spacing(&self) -> f64 {
        self.inner.spacing()
    }

    fn nearest<'py>(&self, py: Python<'py>, query: &Bound<'py, PyAny>) -> PyResult<Nearest<'py>> {
        let q = array2(py, query, 2, "query")?;
        let qs = q.pairs();
        core::check_finite("query", qs).map_err(|e| to_py(py, e))?;
        let inner = self.inner.clone();
        let (d, i): (Vec<f64>, Vec<i64>) = py.detach(|| {
            qs.iter()
                .map(|p| {
                    let (d2, j) = inner.nearest(*p);
                    (d2.sqrt(), j as i64)
                })
                .unzip()
        });
        Ok((d.into_pyarray(py), i.into_pyarray(py)))
    }

    fn within<'py>(
        &self,
        py: Python<'py>,
        center: &Bound<'py, PyAny>,
        radius: f64,
    ) -> PyResult<Bound<'py, PyArray1<i64>>> {
        let c = vector(py, center, "center")?;
        if c.len() != 2 || !c.iter().all(|v| v.is_finite()) {
            return Err(input_err(
                py,
                "center",
                format!("expected 2 finite values, got {c:?}"),
            ));
        }
        if !(radius >= 0.0 && radius.is_finite()) {
            return Err(to_py(
                py,
                CoreError::InvalidConfig {
                    field: "radius",
                    value: radius.to_string(),
                    reason: "must be non-negative and finite",
                },
            ));
        }
        let inner = self.inner.clone();
        let v: Vec<i64> = py.detach(|| {
            inner
                .within([c[0], c[1]], radius)
                .into_iter()
                .map(|i| i as i64)
                .collect()
        });
        Ok(v.into_pyarray(py))
    }

    #[pyo3(signature = (pose, fov=std::f64::consts::PI, max_range=30.0, point_radius=None, tolerance=0.05, angular_resolution=0.0025))]
    #[allow(clippy::too_many_arguments)]
    fn visible<'py>(
        &self,
        py: Python<'py>,
        pose: &Bound<'py, PyAny>,
        fov: f64,
        max_range: f64,
        point_radius: Option<f64>,
        tolerance: f64,
        angular_resolution: f64,
    ) -> PyResult<Bound<'py, PyArray1<i64>>> {
        let pose = pose_arg(py, pose, "pose")?;
        let inner = self.inner.clone();
        let v = py
            .detach(|| {
                guarded(|| {
                    inner.visible(
                        pose,
                        fov,
                        max_range,
                        point_radius,
                        tolerance,
                        angular_resolution,
                    )
                })
            })
            .map_err(|e| to_py(py, e))?;
        let v: Vec<i64> = v.into_iter().map(|i| i as i64).collect();
        Ok(v.into_pyarray(py))
    }
}

fn pairs_to_array<'py>(py: Python<'py>, p: &[[f64; 2]]) -> Bound<'py, PyArray2<f64>> {
    let v: Vec<f64> = p.iter().flatten().copied().collect();
    Array2::from_shape_vec((p.len(), 2), v)
        .expect("N x 2")
        .into_pyarray(py)
}

// ---------------------------------------------------------------- IcpConfig

/// ICP settings: a wrapper of the core's `IcpConfig`, whose `Default` is the one source of
/// every default (see icploc._core.pyi for the meaning of each field). Every value is
/// checked when it is set (at construction or by assignment), the error naming the field.
#[pyclass(name = "IcpConfig", module = "icploc._core")]
#[derive(Clone)]
pub(crate) struct PyIcpConfig {
    pub(crate) inner: core::IcpConfig,
}

/// The field names, in order (constructor keywords, attributes, `to_dict` keys).
const ICP_FIELDS: [&str; 25] = [
    "metric",
    "max_iterations",
    "max_correspondence_distance",
    "min_correspondence_distance",
    "threshold_decay",
    "trim_fraction",
    "robust",
    "robust_scale",
    "mse_threshold",
    "mse_change",
    "step_tolerance",
    "min_inliers",
    "min_inlier_ratio",
    "heading_search",
    "heading_step",
    "position_search",
    "window_search",
    "window_position",
    "window_heading",
    "window_angle_step",
    "expected_noise",
    "accept_inlier_ratio",
    "accept_see_through",
    "prior_sure_rms",
    "vanished_object_size",
];

fn config_err(
    py: Python<'_>,
    field: &'static str,
    v: &Bound<'_, PyAny>,
    reason: &'static str,
) -> PyErr {
    let value = v
        .repr()
        .map(|r| r.to_string())
        .unwrap_or_else(|_| "?".into());
    to_py(
        py,
        CoreError::InvalidConfig {
            field,
            value,
            reason,
        },
    )
}

fn cfg_float(py: Python<'_>, field: &'static str, v: &Bound<'_, PyAny>) -> PyResult<f64> {
    if v.is_instance_of::<pyo3::types::PyBool>() {
        return Err(config_err(py, field, v, "must be a number, not a bool"));
    }
    v.extract::<f64>()
        .map_err(|_| config_err(py, field, v, "must be a number"))
}

fn cfg_count(py: Python<'_>, field: &'static str, v: &Bound<'_, PyAny>) -> PyResult<usize> {
    if v.is_instance_of::<pyo3::types::PyBool>() {
        return Err(config_err(py, field, v, "must be an integer, not a bool"));
    }
    match v.extract::<i64>() {
        Ok(n) if n >= 0 => Ok(n as usize),
        Ok(_) => Err(config_err(py, field, v, "must be a non-negative integer")),
        Err(_) if v.is_instance_of::<pyo3::types::PyInt>() => Err(config_err(
            py,
            field,
            v,
            "is out of range (at most 2**63 - 1)",
        )),
        Err(_) => Err(config_err(py, field, v, "must be an integer")),
    }
}

fn cfg_bool(py: Python<'_>, field: &'static str, v: &Bound<'_, PyAny>) -> PyResult<bool> {
    v.extract::<bool>()
        .map_err(|_| config_err(py, field, v, "must be True or False"))
}

fn cfg_str(py: Python<'_>, field: &'static str, v: &Bound<'_, PyAny>) -> PyResult<String> {
    v.extract::<String>()
        .map_err(|_| config_err(py, field, v, "must be a string"))
}

/// Set one field of `c` from a Python value (type-checked; not yet range-checked).
fn set_icp_field(
    py: Python<'_>,
    c: &mut core::IcpConfig,
    name: &str,
    v: &Bound<'_, PyAny>,
) -> PyResult<()> {
    let Some(&field) = ICP_FIELDS.iter().find(|f| **f == name) else {
        return Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "IcpConfig has no field {name:?} (fields: {})",
            ICP_FIELDS.join(", ")
        )));
    };
    match field {
        "metric" => {
            c.metric = match cfg_str(py, field, v)?.as_str() {
                "point_to_point" => core::Metric::PointToPoint,
                "point_to_line" => core::Metric::PointToLine,
                _ => {
                    return Err(config_err(
                        py,
                        field,
                        v,
                        "must be 'point_to_point' or 'point_to_line'",
                    ))
                }
            }
        }
        "robust" => {
            c.robust = match cfg_str(py, field, v)?.as_str() {
                "none" => core::Robust::None,
                "huber" => core::Robust::Huber,
                "cauchy" => core::Robust::Cauchy,
                _ => {
                    return Err(config_err(
                        py,
                        field,
                        v,
                        "must be 'none', 'huber' or 'cauchy'",
                    ))
                }
            }
        }
        "max_iterations" => c.max_iterations = cfg_count(py, field, v)?,
        "min_inliers" => c.min_inliers = cfg_count(py, field, v)?,
        "window_search" => c.window_search = cfg_bool(py, field, v)?,
        _ => {
            let x = cfg_float(py, field, v)?;
            match field {
                "max_correspondence_distance" => c.max_correspondence_distance = x,
                "min_correspondence_distance" => c.min_correspondence_distance = x,
                "threshold_decay" => c.threshold_decay = x,
                "trim_fraction" => c.trim_fraction = x,
                "robust_scale" => c.robust_scale = x,
                "mse_threshold" => c.mse_threshold = x,
                "mse_change" => c.mse_change = x,
                "step_tolerance" => c.step_tolerance = x,
                "min_inlier_ratio" => c.min_inlier_ratio = x,
                "heading_search" => c.heading_search = x,
                "heading_step" => c.heading_step = x,
                "position_search" => c.position_search = x,
                "window_position" => c.window_position = x,
                "window_heading" => c.window_heading = x,
                "window_angle_step" => c.window_angle_step = x,
                "expected_noise" => c.expected_noise = x,
                "accept_inlier_ratio" => c.accept_inlier_ratio = x,
                "accept_see_through" => c.accept_see_through = x,
                "prior_sure_rms" => c.prior_sure_rms = x,
                "vanished_object_size" => c.vanished_object_size = x,
                _ => unreachable!("every field is handled"),
            }
        }
    }
    Ok(())
}

/// One field of `c` as a Python value.
fn get_icp_field<'py>(
    py: Python<'py>,
    c: &core::IcpConfig,
    name: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let v = match name {
        "metric" => match c.metric {
            core::Metric::PointToPoint => "point_to_point",
            core::Metric::PointToLine => "point_to_line",
        }
        .into_pyobject(py)?
        .into_any(),
        "robust" => match c.robust {
            core::Robust::None => "none",
            core::Robust::Huber => "huber",
            core::Robust::Cauchy => "cauchy",
        }
        .into_pyobject(py)?
        .into_any(),
        "max_iterations" => c.max_iterations.into_pyobject(py)?.into_any(),
        "min_inliers" => c.min_inliers.into_pyobject(py)?.into_any(),
        "window_search" => pyo3::types::PyBool::new(py, c.window_search)
            .to_owned()
            .into_any(),
        "max_correspondence_distance" => {
            c.max_correspondence_distance.into_pyobject(py)?.into_any()
        }
        "min_correspondence_distance" => {
            c.min_correspondence_distance.into_pyobject(py)?.into_any()
        }
        "threshold_decay" => c.threshold_decay.into_pyobject(py)?.into_any(),
        "trim_fraction" => c.trim_fraction.into_pyobject(py)?.into_any(),
        "robust_scale" => c.robust_scale.into_pyobject(py)?.into_any(),
        "mse_threshold" => c.mse_threshold.into_pyobject(py)?.into_any(),
        "mse_change" => c.mse_change.into_pyobject(py)?.into_any(),
        "step_tolerance" => c.step_tolerance.into_pyobject(py)?.into_any(),
        "min_inlier_ratio" => c.min_inlier_ratio.into_pyobject(py)?.into_any(),
        "heading_search" => c.heading_search.into_pyobject(py)?.into_any(),
        "heading_step" => c.heading_step.into_pyobject(py)?.into_any(),
        "position_search" => c.position_search.into_pyobject(py)?.into_any(),
        "window_position" => c.window_position.into_pyobject(py)?.into_any(),
        "window_heading" => c.window_heading.into_pyobject(py)?.into_any(),
        "window_angle_step" => c.window_angle_step.into_pyobject(py)?.into_any(),
        "expected_noise" => c.expected_noise.into_pyobject(py)?.into_any(),
        "accept_inlier_ratio" => c.accept_inlier_ratio.into_pyobject(py)?.into_any(),
        "accept_see_through" => c.accept_see_through.into_pyobject(py)?.into_any(),
        "prior_sure_rms" => c.prior_sure_rms.into_pyobject(py)?.into_any(),
        "vanished_object_size" => c.vanished_object_size.into_pyobject(py)?.into_any(),
        _ => {
            return Err(pyo3::exceptions::PyAttributeError::new_err(format!(
                "IcpConfig has no field {name:?}"
            )))
        }
    };
    Ok(v)
}

impl PyIcpConfig {
    pub(crate) fn to_core(&self) -> core::Result<core::IcpConfig> {
        self.inner.validate()?;
        Ok(self.inner.clone())
    }

    /// Set `name` to `v`, keeping the old value unless the whole config stays valid.
    fn assign(&mut self, py: Python<'_>, name: &str, v: &Bound<'_, PyAny>) -> PyResult<()> {
        let mut c = self.inner.clone();
        set_icp_field(py, &mut c, name, v)?;
        c.validate().map_err(|e| to_py(py, e))?;
        self.inner = c;
        Ok(())
    }
}

macro_rules! icp_pymethods {
    ({ $($extra:tt)* } $($name:ident => $setter:ident),* $(,)?) => {
        #[pymethods]
        impl PyIcpConfig {
            $($extra)*
            $(
                #[getter]
                fn $name<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
                    get_icp_field(py, &self.inner, stringify!($name))
                }
                #[setter]
                fn $setter(&mut self, py: Python<'_>, v: &Bound<'_, PyAny>) -> PyResult<()> {
                    self.assign(py, stringify!($name), v)
                }
            )*
        }
    };
}

icp_pymethods!(
    {
    /// Keyword arguments override the core's defaults (`IcpConfig::default()` in Rust).
    #[new]
    #[pyo3(signature = (**kwargs))]
    fn new(py: Python<'_>, kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let mut c = core::IcpConfig::default();
        if let Some(kw) = kwargs {
            for (k, v) in kw.iter() {
                let name: String = k.extract()?;
                set_icp_field(py, &mut c, &name, &v)?;
            }
        }
        c.validate().map_err(|e| to_py(py, e))?;
        Ok(Self { inner: c })
    }

    fn validate(&self, py: Python<'_>) -> PyResult<()> {
        self.inner.validate().map_err(|e| to_py(py, e))
    }

    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for f in ICP_FIELDS {
            d.set_item(f, get_icp_field(py, &self.inner, f)?)?;
        }
        Ok(d)
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        let mut parts = Vec::new();
        for f in ICP_FIELDS {
            parts.push(format!("{f}={}", get_icp_field(py, &self.inner, f)?.repr()?));
        }
        Ok(format!("IcpConfig({})", parts.join(", ")))
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        match other.extract::<PyRef<'_, PyIcpConfig>>() {
            Ok(o) => self.inner == o.inner,
            Err(_) => false,
        }
    }
    }
    metric => set_metric,
    max_iterations => set_max_iterations,
    max_correspondence_distance => set_max_correspondence_distance,
    min_correspondence_distance => set_min_correspondence_distance,
    threshold_decay => set_threshold_decay,
    trim_fraction => set_trim_fraction,
    robust => set_robust,
    robust_scale => set_robust_scale,
    mse_threshold => set_mse_threshold,
    mse_change => set_mse_change,
    step_tolerance => set_step_tolerance,
    min_inliers => set_min_inliers,
    min_inlier_ratio => set_min_inlier_ratio,
    heading_search => set_heading_search,
    heading_step => set_heading_step,
    position_search => set_position_search,
    window_search => set_window_search,
    window_position => set_window_position,
    window_heading => set_window_heading,
    window_angle_step => set_window_angle_step,
    expected_noise => set_expected_noise,
    accept_inlier_ratio => set_accept_inlier_ratio,
    accept_see_through => set_accept_see_through,
    prior_sure_rms => set_prior_sure_rms,
    vanished_object_size => set_vanished_object_size,
);

// ---------------------------------------------------------------- IcpResult

/// What one ICP alignment did.
#[pyclass(name = "IcpResult", module = "icploc._core", frozen)]
struct PyIcpResult {
    inner: core::IcpResult,
}

#[pymethods]
impl PyIcpResult {
    #[getter]
    fn pose(&self) -> (f64, f64, f64) {
        let p = self.inner.pose;
        (p.x, p.y, p.theta)
    }
    #[getter]
    fn converged(&self) -> bool {
        self.inner.converged
    }
    #[getter]
    fn iterations(&self) -> usize {
        self.inner.iterations
    }
    #[getter]
    fn mse(&self) -> f64 {
        self.inner.mse
    }
    #[getter]
    fn inliers(&self) -> usize {
        self.inner.inliers
    }
    #[getter]
    fn num_points(&self) -> usize {
        self.inner.num_points
    }
    #[getter]
    fn inlier_ratio(&self) -> f64 {
        self.inner.inlier_ratio()
    }
    #[getter]
    fn covariance<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat3(py, &self.inner.covariance)
    }
    #[getter]
    fn information<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat3(py, &self.inner.information)
    }
    #[getter]
    fn degeneracy(&self) -> f64 {
        self.inner.degeneracy
    }
    #[getter]
    fn degenerate_direction(&self) -> (f64, f64) {
        let d = self.inner.degenerate_direction;
        (d[0], d[1])
    }
    #[getter]
    fn termination(&self) -> &'static str {
        self.inner.termination.as_str()
    }
    #[getter]
    fn start(&self) -> &'static str {
        self.inner.start.as_str()
    }
    #[getter]
    fn fit_inlier_ratio(&self) -> Option<f64> {
        self.inner.fit.map(|f| f.inlier_ratio)
    }
    #[getter]
    fn fit_rms(&self) -> Option<f64> {
        self.inner.fit.map(|f| f.rms)
    }
    #[getter]
    fn see_through(&self) -> Option<f64> {
        self.inner.fit.map(|f| f.see_through)
    }
    #[getter]
    fn fit_score(&self) -> Option<f64> {
        self.inner.fit.map(|f| f.score)
    }
    #[getter]
    fn window_score(&self) -> Option<f64> {
        self.inner.window_score
    }
    #[getter]
    fn window_second_score(&self) -> Option<f64> {
        self.inner.window_second
    }

    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        d.set_item("pose", self.pose())?;
        d.set_item("converged", self.inner.converged)?;
        d.set_item("iterations", self.inner.iterations)?;
        d.set_item("mse", self.inner.mse)?;
        d.set_item("inliers", self.inner.inliers)?;
        d.set_item("num_points", self.inner.num_points)?;
        d.set_item("inlier_ratio", self.inner.inlier_ratio())?;
        d.set_item("covariance", self.covariance(py))?;
        d.set_item("information", self.information(py))?;
        d.set_item("degeneracy", self.inner.degeneracy)?;
        d.set_item("degenerate_direction", self.degenerate_direction())?;
        d.set_item("termination", self.termination())?;
        d.set_item("start", self.start())?;
        d.set_item("fit_inlier_ratio", self.fit_inlier_ratio())?;
        d.set_item("fit_rms", self.fit_rms())?;
        d.set_item("see_through", self.see_through())?;
        d.set_item("fit_score", self.fit_score())?;
        d.set_item("window_score", self.window_score())?;
        d.set_item("window_second_score", self.window_second_score())?;
        Ok(d)
    }

    fn __repr__(&self) -> String {
        let p = self.inner.pose;
        format!(
            "IcpResult(pose=({:.6}, {:.6}, {:.6}), converged={}, iterations={}, mse={:.3e}, inliers={}/{}, degeneracy={:.3}, termination='{}', start='{}')",
            p.x,
            p.y,
            p.theta,
            if self.inner.converged { "True" } else { "False" },
            self.inner.iterations,
            self.inner.mse,
            self.inner.inliers,
            self.inner.num_points,
            self.inner.degeneracy,
            self.inner.termination.as_str(),
            self.inner.start.as_str()
        )
    }
}

// ---------------------------------------------------------------- functions

fn config_arg(py: Python<'_>, config: Option<PyRef<'_, PyIcpConfig>>) -> PyResult<core::IcpConfig> {
    match config {
        Some(c) => c.to_core().map_err(|e| to_py(py, e)),
        None => Ok(core::IcpConfig::default()),
    }
}

/// Align an (N, 2) scan in the sensor frame to the map, starting from `initial_pose`.
#[pyfunction]
#[pyo3(signature = (scan_xy, index, initial_pose, config=None))]
fn icp(
    py: Python<'_>,
    scan_xy: &Bound<'_, PyAny>,
    index: &Bound<'_, PyMapIndex>,
    initial_pose: &Bound<'_, PyAny>,
    config: Option<PyRef<'_, PyIcpConfig>>,
) -> PyResult<PyIcpResult> {
    let scan = array2(py, scan_xy, 2, "scan_xy")?;
    let pose = pose_fast(py, initial_pose, "initial_pose")?;
    let cfg = config_arg(py, config)?;
    let idx = index.get().inner.clone();
    let s = scan.pairs();
    let r = py
        .detach(|| guarded(|| core::align(s, &idx, pose, &cfg)))
        .map_err(|e| to_py(py, e))?;
    Ok(PyIcpResult { inner: r })
}

/// Align many (scan, initial pose) pairs in parallel with the GIL released.
#[pyfunction]
#[pyo3(signature = (scans, index, initial_poses, config=None, num_threads=None))]
fn icp_batch(
    py: Python<'_>,
    scans: &Bound<'_, PyAny>,
    index: &Bound<'_, PyMapIndex>,
    initial_poses: &Bound<'_, PyAny>,
    config: Option<PyRef<'_, PyIcpConfig>>,
    num_threads: Option<&Bound<'_, PyAny>>,
) -> PyResult<Vec<PyIcpResult>> {
    let cfg = config_arg(py, config)?;
    let num_threads = match num_threads {
        Some(v) if !v.is_none() => {
            let n = cfg_count(py, "num_threads", v)?;
            if n == 0 {
                return Err(config_err(py, "num_threads", v, "must be at least 1"));
            }
            Some(n)
        }
        _ => None,
    };
    let mut arrays = Vec::new();
    for (k, s) in scans.try_iter()?.enumerate() {
        arrays.push(array2(py, &s?, 2, &format!("scans[{k}]"))?);
    }
    let poses_arr = array2(py, initial_poses, 3, "initial_poses")?;
    let poses: Vec<Pose2> = poses_arr
        .flat()
        .chunks_exact(3)
        .map(|c| Pose2::new(c[0], c[1], c[2]))
        .collect();
    let slices: Vec<&[[f64; 2]]> = arrays.iter().map(|a| a.pairs()).collect();
    let idx = index.get().inner.clone();
    let results = py
        .detach(|| guarded(|| core::align_batch(&slices, &idx, &poses, &cfg, num_threads)))
        .map_err(|e| to_py(py, e))?;
    results
        .into_iter()
        .enumerate()
        .map(|(k, r)| match r {
            Ok(inner) => Ok(PyIcpResult { inner }),
            Err(e) => {
                let e = match e {
                    CoreError::InvalidInput { what, reason } => CoreError::InvalidInput {
                        what: format!("pair {k}: {what}"),
                        reason,
                    },
                    other => other,
                };
                Err(to_py(py, e))
            }
        })
        .collect()
}

/// Ranges from `pose` along each beam to the nearest of the (K, 4) segments.
#[pyfunction]
fn raycast<'py>(
    py: Python<'py>,
    segments: &Bound<'py, PyAny>,
    pose: &Bound<'py, PyAny>,
    angles: &Bound<'py, PyAny>,
    max_range: f64,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let seg = array2(py, segments, 4, "segments")?;
    let pose = pose_arg(py, pose, "pose")?;
    let ang = vector(py, angles, "angles")?;
    let f = seg.flat();
    let segs: Vec<[f64; 4]> = f
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect();
    let r = py
        .detach(|| guarded(|| core::raycast::raycast(&segs, pose, &ang, max_range)))
        .map_err(|e| to_py(py, e))?;
    Ok(r.into_pyarray(py))
}

/// Parse whitespace-separated floats (decimal, exponent, nan, inf) from text, exactly.
#[pyfunction]
fn parse_floats<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let v = py
        .detach(|| guarded(|| core::text::parse_floats(text)))
        .map_err(|e| to_py(py, e))?;
    Ok(v.into_pyarray(py))
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("IcpError", icp_error(py).bind(py))?;
    m.add("InvalidInputError", invalid_input(py).bind(py))?;
    m.add("EmptyMapError", empty_map(py).bind(py))?;
    m.add("GridTooLargeError", grid_too_large(py).bind(py))?;
    m.add("InvalidConfigError", invalid_config(py).bind(py))?;
    m.add_class::<PyMapIndex>()?;
    m.add_class::<PyIcpConfig>()?;
    m.add_class::<PyIcpResult>()?;
    m.add_function(wrap_pyfunction!(icp, m)?)?;
    m.add_function(wrap_pyfunction!(icp_batch, m)?)?;
    m.add_function(wrap_pyfunction!(raycast, m)?)?;
    m.add_function(wrap_pyfunction!(parse_floats, m)?)?;
    global::register(m)?;
    maps::register(m)?;
    gridstore::register(m)?;
    perscan::register(m)?;
    Ok(())
}
