"""Fusing a scan match with the odometry prediction: one information update, a chi-square gate.

* :func:`scan_covariance` turns an ICP result into a covariance that is true on real maps
  rather than ``sigma^2 H^-1`` taken at face value. That textbook form treats every beam as
  an independent measurement; on a real map the beams that hit one wall share that wall's
  error (a grid's quantisation, a line fitted to a wall two or three cells thick, the wall
  itself not being straight), so hundreds of beams carry the information of a few walls.
  The covariance used is ``s^2 (H / n)^-1 / n_eff``: the mean per-beam geometry ``H / n``
  of the fit, ``n_eff`` independent measurements (``localizer.scan_independent_beams``),
  and a per-beam noise ``s^2`` that is the fit's own residual variance but never below the
  map's expected residual (from its resolution and its measured fit quality).
* :func:`fuse` combines the prediction ``(x_p, P)`` with the scan's pose ``(z, R)`` in one
  information update, ``P+ = (P^-1 + R^-1)^-1``, ``x+ = x_p + P+ R^-1 (z - x_p)``: a
  corridor's open axis, where ``R`` is huge, keeps the prediction, and across it the scan
  wins — no rule, just the information each carries.
* :func:`mahalanobis2` is the consistency of the two: ``v' (P + R)^-1 v`` with ``v = z - x_p``
  is chi-square with 3 degrees of freedom when both covariances are right; the localizer
  accepts below one quantile, inflates ``R`` up to a second, rejects beyond.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from icploc.se2 import Pose, wrap_angle

__all__ = ["CHI2_3", "fuse", "mahalanobis2", "scan_covariance"]

#: chi-square quantiles with 3 degrees of freedom (probability -> value)
CHI2_3 = {0.9: 6.251, 0.95: 7.815, 0.99: 11.345, 0.999: 16.266, 0.9999: 21.108}

#: largest variance given to a direction the scan does not constrain (m^2 / rad^2)
_HUGE = 1e6


def scan_covariance(
    information: NDArray[np.float64],
    inliers: int,
    mse: float,
    sigma_floor: float,
    independent_beams: float,
) -> NDArray[np.float64]:
    """Covariance of an ICP pose (see the module docstring). ``information`` is the fit's
    ``H = sum J' J`` over its ``inliers`` pairs, ``mse`` their mean squared residual (m^2),
    ``sigma_floor`` the map's expected per-beam residual (m)."""
    n = max(int(inliers), 1)
    H = np.asarray(information, dtype=np.float64).reshape(3, 3)
    s2 = max(float(mse) if math.isfinite(mse) else 0.0, sigma_floor * sigma_floor)
    neff = min(float(independent_beams), float(n))
    info = (H + H.T) * (0.5 * neff / (n * s2))
    if not np.isfinite(info).all():
        return np.eye(3) * _HUGE
    # a direction the scan does not constrain gets a variance of about _HUGE
    info[0, 0] += 1.0 / _HUGE
    info[1, 1] += 1.0 / _HUGE
    info[2, 2] += 1.0 / _HUGE
    try:
        cov: NDArray[np.float64] = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return np.eye(3) * _HUGE
    return (cov + cov.T) * 0.5


def _residual(z: Pose, x: Pose) -> NDArray[np.float64]:
    return np.array([z[0] - x[0], z[1] - x[1], wrap_angle(z[2] - x[2])])


def mahalanobis2(
    pred: Pose, P: NDArray[np.float64], meas: Pose, R: NDArray[np.float64]
) -> float:
    """``v' (P + R)^-1 v`` with ``v = meas - pred`` (heading wrapped)."""
    v = _residual(meas, pred)
    S = P + R
    try:
        return float(v @ np.linalg.solve(S, v))
    except np.linalg.LinAlgError:
        return math.inf


def fuse(
    pred: Pose, P: NDArray[np.float64], meas: Pose, R: NDArray[np.float64]
) -> tuple[Pose, NDArray[np.float64]]:
    """Information update of the prediction ``(pred, P)`` with the measurement ``(meas, R)``.
    Written as the Kalman form ``K = P (P + R)^-1`` (the same update, stable when ``R`` is
    huge along an axis)."""
    v = _residual(meas, pred)
    S = P + R
    try:
        K = np.linalg.solve(S.T, P.T).T  # P S^-1
    except np.linalg.LinAlgError:
        return pred, P
    dx = K @ v
    I_K = np.eye(3) - K
    # Joseph form: symmetric and positive whatever the rounding
    cov = I_K @ P @ I_K.T + K @ R @ K.T
    cov = (cov + cov.T) * 0.5
    return (pred[0] + dx[0], pred[1] + dx[1], wrap_angle(pred[2] + dx[2])), cov
