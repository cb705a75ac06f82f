//! `icploc._core` helpers to save and restore a `MapIndex`'s closest-point grid (the
//! prepared-map cache keeps it, `icploc.maps.cache`): the grid's cells as runs
//! (`icploc_core::index::runs`) out, and an index rebuilt from its points and those runs in,
//! without computing the grid again. Arrays come in zero-copy; the GIL is released for the
//! work.

use std::sync::Arc;

use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;

use icploc_core as core;
use icploc_core::index::runs;

use crate::{array2, guarded, input_err, to_py, PyMapIndex};

type Runs<'py> = (Bound<'py, PyArray1<u32>>, Bound<'py, PyArray1<u32>>, f64);

/// `(values, lengths, resolution)`: the index's closest-point grid cells as runs, or None
/// when it has no grid.
#[pyfunction]
fn grid_runs<'py>(py: Python<'py>, index: &PyMapIndex) -> Option<Runs<'py>> {
    let inner = index.inner.clone();
    let res = inner.cache_resolution()?;
    let (v, n) = py.detach(|| runs::encode(&inner.cache_cells().unwrap_or_default()));
    Some((v.into_pyarray(py), n.into_pyarray(py), res))
}

/// The `MapIndex(points, normals, cache_resolution=resolution)` whose grid cells `grid_runs`
/// returned as `(values, lengths)`, rebuilt without computing them. Runs that do not fit
/// the grid these points give raise `InvalidInputError`.
#[pyfunction]
#[pyo3(signature = (points, normals, resolution, values, lengths))]
fn index_from_grid_runs(
    py: Python<'_>,
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
    resolution: f64,
    values: PyReadonlyArray1<'_, u32>,
    lengths: PyReadonlyArray1<'_, u32>,
) -> PyResult<PyMapIndex> {
    let p = array2(py, points, 2, "map points")?;
    let n = match normals {
        Some(n) if !n.is_none() => Some(array2(py, n, 2, "map normals")?),
        _ => None,
    };
    let (Ok(v), Ok(l)) = (values.as_slice(), lengths.as_slice()) else {
        return Err(input_err(
            py,
            "grid runs",
            "must be contiguous uint32 arrays".into(),
        ));
    };
    let pv = p.pairs().to_vec();
    let nv = n.as_ref().map(|a| a.pairs().to_vec());
    let values = v.to_vec();
    let idx = py
        .detach(|| guarded(|| core::MapIndex::new(pv, nv)?.with_cache_runs(resolution, values, l)))
        .map_err(|e| to_py(py, e))?;
    Ok(PyMapIndex {
        inner: Arc::new(idx),
    })
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add(
        "DEFAULT_CACHE_RESOLUTION",
        core::index::DEFAULT_CACHE_RESOLUTION,
    )?;
    m.add("GRID_FILL_VERSION", core::index::GRID_FILL_VERSION)?;
    m.add_function(wrap_pyfunction!(grid_runs, m)?)?;
    m.add_function(wrap_pyfunction!(index_from_grid_runs, m)?)?;
    Ok(())
}
