//! `icploc._core` map helpers: wall-line extraction from occupancy grids
//! (`icploc_core::gridlines`) and ray casting into a grid (`icploc_core::gridcast`).
//! Grids come in zero-copy (C-contiguous uint8 / bool), the GIL is released for the work.

use numpy::ndarray::Array2;
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use icploc_core::gridcast::{
    cast_rays as core_cast_rays, grid_visible as core_grid_visible, GridGeometry,
};
use icploc_core::gridlines::{extract_lines, GridLines, LineConfig};

use crate::{array2, guarded, input_err, pairs_to_array, to_py};

/// Result of `extract_grid_lines`: lines, leftover surface points and how much is explained.
#[pyclass(name = "GridLines", module = "icploc._core", frozen)]
pub struct PyGridLines {
    inner: GridLines,
}

#[pymethods]
impl PyGridLines {
    /// (K, 4) lines [x1, y1, x2, y2] in cell-corner units; the left normal faces free space.
    #[getter]
    fn lines<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let k = self.inner.lines.len();
        let flat: Vec<f64> = self.inner.lines.iter().flat_map(|l| l.segment).collect();
        Array2::from_shape_vec((k, 4), flat)
            .expect("k x 4")
            .into_pyarray(py)
    }
    /// (K,) RMS residual of each line's fit [cells].
    #[getter]
    fn rms<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = self.inner.lines.iter().map(|l| l.rms).collect();
        v.into_pyarray(py)
    }
    /// (K,) face edges supporting each line.
    #[getter]
    fn support<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        let v: Vec<i64> = self.inner.lines.iter().map(|l| l.support as i64).collect();
        v.into_pyarray(py)
    }
    /// (K,) standard deviation of each line's direction [radians].
    #[getter]
    fn sigma_angle<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = self.inner.lines.iter().map(|l| l.sigma_angle).collect();
        v.into_pyarray(py)
    }
    /// (K,) whether each line was snapped to the dominant direction.
    #[getter]
    fn snapped<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<bool>> {
        let v: Vec<bool> = self.inner.lines.iter().map(|l| l.snapped).collect();
        v.into_pyarray(py)
    }
    /// (M, 2) unexplained surface points in cell-corner units.
    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        pairs_to_array(py, &self.inner.points)
    }
    /// (M, 2) unit normals of `points`, facing free space.
    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        pairs_to_array(py, &self.inner.normals)
    }
    #[getter]
    fn surface_cells(&self) -> usize {
        self.inner.surface_cells
    }
    #[getter]
    fn explained_cells(&self) -> usize {
        self.inner.explained_cells
    }
    #[getter]
    fn explained_fraction(&self) -> f64 {
        self.inner.explained_fraction()
    }
    #[getter]
    fn face_edges(&self) -> usize {
        self.inner.face_edges
    }
    /// Dominant direction mod 90 degrees [radians], or None.
    #[getter]
    fn dominant_direction(&self) -> Option<f64> {
        self.inner.dominant_direction
    }
    fn __repr__(&self) -> String {
        format!(
            "GridLines(lines={}, points={}, explained_fraction={:.4})",
            self.inner.lines.len(),
            self.inner.points.len(),
            self.inner.explained_fraction()
        )
    }
}

fn config_dict<'py>(py: Python<'py>, c: &LineConfig) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("split_tolerance", c.split_tolerance)?;
    d.set_item("min_length", c.min_length)?;
    d.set_item("max_gap", c.max_gap)?;
    d.set_item("join_angle_deg", c.join_angle_deg)?;
    d.set_item("join_offset", c.join_offset)?;
    d.set_item("max_rms", c.max_rms)?;
    d.set_item("snap", c.snap)?;
    d.set_item("snap_sigmas", c.snap_sigmas)?;
    d.set_item("surface_offset", c.surface_offset)?;
    d.set_item("unknown_rim", c.unknown_rim)?;
    Ok(d)
}

/// The defaults of `extract_grid_lines` (lengths in cells), from the core.
#[pyfunction]
fn grid_line_defaults<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
    config_dict(py, &LineConfig::default())
}

/// Wall lines of an occupancy grid `cells[iy, ix]` (uint8: 0 free, 1 occupied, other
/// unknown; C-contiguous). Settings left as None take the core's defaults.
#[pyfunction]
#[pyo3(signature = (cells, *, split_tolerance=None, min_length=None, max_gap=None,
    join_angle_deg=None, join_offset=None, max_rms=None, snap=None, snap_sigmas=None,
    surface_offset=None, unknown_rim=None))]
#[allow(clippy::too_many_arguments)]
fn extract_grid_lines(
    py: Python<'_>,
    cells: PyReadonlyArray2<'_, u8>,
    split_tolerance: Option<f64>,
    min_length: Option<f64>,
    max_gap: Option<f64>,
    join_angle_deg: Option<f64>,
    join_offset: Option<f64>,
    max_rms: Option<f64>,
    snap: Option<bool>,
    snap_sigmas: Option<f64>,
    surface_offset: Option<f64>,
    unknown_rim: Option<usize>,
) -> PyResult<PyGridLines> {
    let d = LineConfig::default();
    let cfg = LineConfig {
        split_tolerance: split_tolerance.unwrap_or(d.split_tolerance),
        min_length: min_length.unwrap_or(d.min_length),
        max_gap: max_gap.unwrap_or(d.max_gap),
        join_angle_deg: join_angle_deg.unwrap_or(d.join_angle_deg),
        join_offset: join_offset.unwrap_or(d.join_offset),
        max_rms: max_rms.unwrap_or(d.max_rms),
        snap: snap.unwrap_or(d.snap),
        snap_sigmas: snap_sigmas.unwrap_or(d.snap_sigmas),
        surface_offset: surface_offset.unwrap_or(d.surface_offset),
        unknown_rim: unknown_rim.unwrap_or(d.unknown_rim),
    };
    let shape = cells.shape();
    let (h, w) = (shape[0], shape[1]);
    let flat = cells
        .as_slice()
        .map_err(|_| input_err(py, "cells", "must be a C-contiguous uint8 array".into()))?;
    let r = py
        .detach(|| guarded(|| extract_lines(flat, w, h, &cfg)))
        .map_err(|e| to_py(py, e))?;
    Ok(PyGridLines { inner: r })
}

/// Ray casting into a grid: returns (hits, passes), (height, width) uint32 arrays.
#[pyfunction]
#[pyo3(signature = (origins, ends, hit, origin, resolution, width, height))]
#[allow(clippy::too_many_arguments)]
#[allow(clippy::type_complexity)]
fn cast_rays<'py>(
    py: Python<'py>,
    origins: &Bound<'py, PyAny>,
    ends: &Bound<'py, PyAny>,
    hit: PyReadonlyArray1<'py, bool>,
    origin: (f64, f64),
    resolution: f64,
    width: usize,
    height: usize,
) -> PyResult<(Bound<'py, PyArray2<u32>>, Bound<'py, PyArray2<u32>>)> {
    let o = array2(py, origins, 2, "origins")?;
    let e = array2(py, ends, 2, "ends")?;
    let hit = hit
        .as_slice()
        .map_err(|_| input_err(py, "hit", "must be a contiguous bool array".into()))?;
    let g = GridGeometry {
        origin: [origin.0, origin.1],
        resolution,
        width,
        height,
    };
    let (op, ep) = (o.pairs(), e.pairs());
    let r = py
        .detach(|| guarded(|| core_cast_rays(&g, op, ep, hit)))
        .map_err(|err| to_py(py, err))?;
    let hits = Array2::from_shape_vec((height, width), r.hits).expect("h x w");
    let passes = Array2::from_shape_vec((height, width), r.passes).expect("h x w");
    Ok((hits.into_pyarray(py), passes.into_pyarray(py)))
}

/// Which targets (N, 2) a sensor sees through the class grid `cells[iy, ix]` (0 free, else
/// blocking), in the grid's frame: a (N,) bool array.
#[pyfunction]
#[pyo3(signature = (cells, origin, resolution, sensor, targets, tolerance))]
fn grid_visible<'py>(
    py: Python<'py>,
    cells: PyReadonlyArray2<'py, u8>,
    origin: (f64, f64),
    resolution: f64,
    sensor: (f64, f64),
    targets: &Bound<'py, PyAny>,
    tolerance: f64,
) -> PyResult<Bound<'py, PyArray1<bool>>> {
    let shape = cells.shape();
    let g = GridGeometry {
        origin: [origin.0, origin.1],
        resolution,
        width: shape[1],
        height: shape[0],
    };
    let flat = cells
        .as_slice()
        .map_err(|_| input_err(py, "cells", "must be a C-contiguous uint8 array".into()))?;
    let t = array2(py, targets, 2, "targets")?;
    let tp = t.pairs();
    let r = py
        .detach(|| guarded(|| core_grid_visible(flat, &g, [sensor.0, sensor.1], tp, tolerance)))
        .map_err(|e| to_py(py, e))?;
    Ok(r.into_pyarray(py))
}

/// Add the map helpers to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyGridLines>()?;
    m.add_function(wrap_pyfunction!(grid_line_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(extract_grid_lines, m)?)?;
    m.add_function(wrap_pyfunction!(cast_rays, m)?)?;
    m.add_function(wrap_pyfunction!(grid_visible, m)?)?;
    Ok(())
}
