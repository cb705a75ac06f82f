//! The localizer's per-scan arithmetic that ran in numpy: the verification evidence of a
//! pose (`fit_score`, for `icploc.fitcheck.FitChecker`), the online odometry noise factor
//! (`noise_factor`, for `icploc.motion.NoiseGain`) and the scan match's covariance
//! (`scan_covariance`, for `icploc.fusion.scan_covariance`). Small inputs, called several
//! times a scan: the arguments are read without numpy conversions (tuples as they are,
//! 3x3 arrays element by element), the results are plain floats or one 3x3 array.

use std::borrow::Cow;

use numpy::{PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use icploc_core as core;
use icploc_core::Pose2;

use crate::{array2, input_err, mat3, pose_fast, PyMapIndex};

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

/// The (3, 3) covariance of an ICP pose from its fit's `information` (see
/// `icploc_core::fusion`); None when a direction may be held by fewer than
/// `min_axis_beams` beams (the caller's eigen-decomposition decides).
#[pyfunction]
fn scan_covariance<'py>(
    py: Python<'py>,
    information: &Bound<'py, PyAny>,
    inliers: i64,
    mse: f64,
    sigma_floor: f64,
    independent_beams: f64,
    min_axis_beams: f64,
) -> PyResult<Option<Bound<'py, PyArray2<f64>>>> {
    let h = mat3_arg(py, information, "information")?;
    Ok(core::fusion::scan_covariance(
        &h,
        inliers,
        mse,
        sigma_floor,
        independent_beams,
        min_axis_beams,
    )
    .map(|c| mat3(py, &c)))
}

/// A 1-D array's values: borrowed when contiguous, else copied.
fn slice<'a, T: numpy::Element + Copy>(a: &'a PyReadonlyArray1<'_, T>) -> Cow<'a, [T]> {
    match a.as_slice() {
        Ok(s) => Cow::Borrowed(s),
        Err(_) => Cow::Owned(a.as_array().iter().copied().collect()),
    }
}

/// The (M, 2) robot-frame points of a scan's usable beams (see `icploc_core::scanprep`):
/// `ranges`, `flags` (or None), `cos` and `sin` of the beam angles plus the laser's
/// heading, all of one length.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn prepare_points<'py>(
    py: Python<'py>,
    ranges: PyReadonlyArray1<'py, f64>,
    flags: Option<PyReadonlyArray1<'py, u8>>,
    cos: PyReadonlyArray1<'py, f64>,
    sin: PyReadonlyArray1<'py, f64>,
    lo: f64,
    hi: f64,
    decimation: usize,
    bad_flags: u8,
    offset: (f64, f64),
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let n = ranges.len();
    let lens = [cos.len(), sin.len(), flags.as_ref().map_or(n, |f| f.len())];
    if lens.iter().any(|&k| k != n) {
        return Err(input_err(
            py,
            "prepare_points",
            format!("ranges, cos, sin and flags must be of one length, got {n} and {lens:?}"),
        ));
    }
    let (r, c, s) = (slice(&ranges), slice(&cos), slice(&sin));
    let f = flags.as_ref().map(slice);
    let pts = py.detach(|| {
        core::scanprep::prepare_points(
            &r,
            f.as_deref(),
            &c,
            &s,
            lo,
            hi,
            decimation,
            bad_flags,
            [offset.0, offset.1],
        )
    });
    Ok(crate::pairs_to_array(py, &pts))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(prepare_points, m)?)?;
    m.add_function(wrap_pyfunction!(scan_covariance, m)?)?;
    m.add_function(wrap_pyfunction!(fit_score, m)?)?;
    m.add_function(wrap_pyfunction!(noise_factor, m)?)?;
    Ok(())
}
