//! The localizer's per-scan arithmetic that ran in numpy: the verification evidence of a
//! pose (`fit_score`, for `icploc.fitcheck.FitChecker`) and the online odometry noise
//! factor (`noise_factor`, for `icploc.motion.NoiseGain`). Small inputs, called several
//! times a scan: the arguments are read without numpy conversions (tuples as they are,
//! 3x3 arrays element by element), the result is plain floats.

use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use icploc_core as core;
use icploc_core::Pose2;

use crate::{array2, input_err, pose_fast, PyMapIndex};

/// A (3, 3) float array (any layout), else a clear error naming it.
fn mat3_arg(py: Python<'_>, obj: &Bound<'_, PyAny>, what: &str) -> PyResult<[[f64; 3]; 3]> {
    let a: PyReadonlyArray2<'_, f64> = match obj.extract() {
        Ok(a) => a,
        Err(_) => {
            let np = py.import("numpy")?;
            np.call_method1("asarray", (obj, "float64"))
                .map_err(|e| {
                    input_err(py, what, format!("cannot convert to a float64 array: {e}"))
                })?
                .extract()
                .map_err(|_| input_err(py, what, "expected a (3, 3) array".into()))?
        }
    };
    if a.shape() != [3, 3] {
        return Err(input_err(
            py,
            what,
            format!("expected a (3, 3) array, got shape {:?}", a.shape()),
        ));
    }
    let v = a.as_array();
    let mut m = [[0.0f64; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = v[[i, j]];
        }
    }
    Ok(m)
}

/// `(hit, rms, beams)`: the evidence of the (N, 2) scan `points` (robot frame) at `pose`
/// on `index` (see `icploc_core::fitscore`).
#[pyfunction]
fn fit_score(
    py: Python<'_>,
    index: &Bound<'_, PyMapIndex>,
    points: &Bound<'_, PyAny>,
    pose: &Bound<'_, PyAny>,
    max_beams: usize,
    hit_distance: f64,
) -> PyResult<(f64, f64, usize)> {
    let pts = array2(py, points, 2, "points")?;
    let pose: Pose2 = pose_fast(py, pose, "pose")?;
    let idx = index.get().inner.clone();
    let s = pts.pairs();
    let r = py.detach(|| core::fitscore::fit_score(&idx, s, pose, max_beams, hit_distance));
    Ok((r.hit, r.rms, r.beams))
}

/// The odometry noise factor of one trusted scan pose (see `icploc_core::noisegain`):
/// `v` the scan pose minus the prediction, `p` and `r` their covariances; None when an
/// input is not finite.
#[pyfunction]
fn noise_factor(
    py: Python<'_>,
    v: (f64, f64, f64),
    p: &Bound<'_, PyAny>,
    r: &Bound<'_, PyAny>,
    max_gain: f64,
) -> PyResult<Option<f64>> {
    let p = mat3_arg(py, p, "P")?;
    let r = mat3_arg(py, r, "R")?;
    Ok(core::noisegain::noise_factor(
        &[v.0, v.1, v.2],
        &p,
        &r,
        max_gain,
    ))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(fit_score, m)?)?;
    m.add_function(wrap_pyfunction!(noise_factor, m)?)?;
    Ok(())
}
