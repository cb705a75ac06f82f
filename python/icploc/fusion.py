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

from icploc import _core
from icploc.se2 import Pose, wrap_angle

__all__ = [
    "CHI2_3",
    "CHI2_3_MEDIAN",
    "axis_measurements",
    "chi2_3_same_tail",
    "fuse",
    "heading_nis",
    "mahalanobis2",
    "scan_covariance",
]

#: chi-square quantiles with 3 degrees of freedom (probability -> value): the gate's
#: quantiles (the tables' values, 3 decimals; scipy is not imported for them)
CHI2_3 = {0.9: 6.251, 0.95: 7.815, 0.99: 11.345, 0.999: 16.266, 0.9999: 21.108}
#: ... and its median (the 0.5 quantile; icploc.motion.NoiseGain solves for it)
CHI2_3_MEDIAN = 2.366

#: largest variance given to a direction the scan does not constrain (m^2 / rad^2)
_HUGE = 1e6


Mat3 = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]


def _inv3(m: list[list[float]]) -> Mat3 | None:
    """Inverse of a symmetric 3x3 (by cofactors, in floats: this runs several times a scan);
    None when it is not positive definite."""
    (s00, s01, s02), (_, s11, s12), (_, _, s22) = m
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    det = s00 * c00 + s01 * c01 + s02 * c02
    if not (det > 0.0 and math.isfinite(det)):
        return None
    c11 = s00 * s22 - s02 * s02
    c12 = s01 * s02 - s00 * s12
    c22 = s00 * s11 - s01 * s01
    k = 1.0 / det
    return (
        (c00 * k, c01 * k, c02 * k),
        (c01 * k, c11 * k, c12 * k),
        (c02 * k, c12 * k, c22 * k),
    )


def _may_be_below(Ha: NDArray[np.float64], bound: float) -> bool:
    """hook (clispeed): False when the smallest eigenvalue of H's symmetric translational
    block is surely >= ``bound`` (closed form, with a margin far above both its and
    LAPACK's rounding), so that ``np.linalg.eigh`` (~25 us) runs only where it may decide."""
    a, b, c = float(Ha[0, 0]), 0.5 * (float(Ha[0, 1]) + float(Ha[1, 0])), float(Ha[1, 1])
    low = 0.5 * (a + c) - math.hypot(0.5 * (a - c), b)
    return not low - bound > 1e-9 * (abs(a) + abs(b) + abs(c) + abs(bound) + 1.0)


def axis_measurements(information: NDArray[np.float64], inliers: int, independent_beams: float) -> float:
    """How many independent measurements :func:`scan_covariance` gives the fit along its
    weakest direction of position: ``lambda_min n_eff / n`` (``lambda_min`` the smallest
    eigenvalue of the translational block of ``H``, unit normals: the beams along it)."""
    Ha = np.asarray(information, dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(Ha)):
        return 0.0
    a, b, c = float(Ha[0, 0]), 0.5 * (float(Ha[0, 1]) + float(Ha[1, 0])), float(Ha[1, 1])
    low = max(0.5 * (a + c) - math.hypot(0.5 * (a - c), b), 0.0)
    n = max(int(inliers), 1)
    return low * min(float(independent_beams), float(n)) / n


def scan_covariance(
    information: NDArray[np.float64],
    inliers: int,
    mse: float,
    sigma_floor: float,
    independent_beams: float,
    min_axis_beams: float = 0.0,
    min_axis_independent: float = 0.0,
) -> NDArray[np.float64]:
    """Covariance of an ICP pose (see the module docstring). ``information`` is the fit's
    ``H = sum J' J`` over its ``inliers`` pairs, ``mse`` their mean squared residual (m^2),
    ``sigma_floor`` the map's expected per-beam residual (m).

    ``min_axis_beams``: the normals are unit vectors, so the smallest eigenvalue of H's
    translational block counts the beams that constrain the position along its weakest
    direction. Fewer than this (a corridor's or an aisle's length, held by the odd shelf
    end or door frame) is no measurement: one ambiguous pairing moves the fit along it by
    a gap while the covariance claims centimetres, and the prediction's own covariance
    along it shrinks for nothing. That direction is then left unconstrained.

    ``min_axis_independent``: the covariance gives the fit ``n_eff`` independent
    measurements spread by its mean geometry ``H / n``, so along the weakest direction it
    counts ``lambda_min n_eff / n`` of them. Fewer than this (a corridor's length, held by
    a door frame or two while hundreds of beams hold its width: translational degeneracy
    under about 0.2 with ``n_eff`` 6) is no measurement either: the fit along it stays
    wherever its prediction put it (real corridors: 3-20 cm a scan of slide, followed, with
    a covariance of 3-5 cm while 0.6 m off), and fused it would shrink the pose's
    covariance along it for nothing. The direction is left unconstrained, so the fused
    pose takes the odometry's growing covariance along it."""
    Ha = information
    if not (isinstance(Ha, np.ndarray) and Ha.shape == (3, 3)):
        Ha = np.asarray(information, dtype=np.float64).reshape(3, 3)
    if min_axis_independent > 0.0:
        n_used = max(int(inliers), 1)
        share = min(float(independent_beams), float(n_used)) / n_used
        min_axis_beams = max(min_axis_beams, min_axis_independent / share)
    # the core computes it, to the bit as below, unless the weak axis may be dropped
    got = _core.scan_covariance(Ha, inliers, mse, sigma_floor, independent_beams, min_axis_beams)
    if got is not None:
        return got
    n = max(int(inliers), 1)
    Ha = np.asarray(Ha, dtype=np.float64)
    if min_axis_beams > 0.0 and np.all(np.isfinite(Ha)) and _may_be_below(Ha, min_axis_beams):
        w, v = np.linalg.eigh(0.5 * (Ha[:2, :2] + Ha[:2, :2].T))
        if w[0] < min_axis_beams:
            u = np.array([v[0, 0], v[1, 0], 0.0])
            # drop the information along u (and its coupling with the heading)
            proj = np.eye(3) - np.outer(u, u)
            Ha = proj @ Ha @ proj
    H = Ha.tolist()
    s2 = max(float(mse) if math.isfinite(mse) else 0.0, sigma_floor * sigma_floor)
    f = min(float(independent_beams), float(n)) / (n * s2)
    eps = 1.0 / _HUGE  # a direction the scan does not constrain: variance about _HUGE
    info = [
        [H[0][0] * f + eps, 0.5 * (H[0][1] + H[1][0]) * f, 0.5 * (H[0][2] + H[2][0]) * f],
        [0.0, H[1][1] * f + eps, 0.5 * (H[1][2] + H[2][1]) * f],
        [0.0, 0.0, H[2][2] * f + eps],
    ]
    inv = _inv3(info)
    if inv is None:
        return np.eye(3) * _HUGE
    return np.array(inv)


def mahalanobis2(
    pred: Pose, P: NDArray[np.float64], meas: Pose, R: NDArray[np.float64]
) -> float:
    """``v' (P + R)^-1 v`` with ``v = meas - pred`` (heading wrapped)."""
    Si = _inv3((P + R).tolist())
    if Si is None:
        return math.inf
    v0, v1, v2 = meas[0] - pred[0], meas[1] - pred[1], wrap_angle(meas[2] - pred[2])
    return (
        Si[0][0] * v0 * v0
        + Si[1][1] * v1 * v1
        + Si[2][2] * v2 * v2
        + 2.0 * (Si[0][1] * v0 * v1 + Si[0][2] * v0 * v2 + Si[1][2] * v1 * v2)
    )


def heading_nis(
    pred: Pose, P: NDArray[np.float64], meas: Pose, R: NDArray[np.float64]
) -> float:
    """The heading's own chi-square statistic (1 dof), ``v_t^2 / (P + R)_tt``: the
    heading innovation tested against the heading variance alone, whatever the position's
    covariance (the joint :func:`mahalanobis2` lets a heading innovation hide in a wide
    position covariance correlated with it)."""
    s = float(P[2, 2] + R[2, 2])
    if not s > 0.0:
        return math.inf
    v = wrap_angle(meas[2] - pred[2])
    return v * v / s


def chi2_3_same_tail(x1: float) -> float:
    """The 3-dof chi-square value with the same upper tail probability as ``x1`` has with
    1 dof (so one per-axis statistic can be read against the joint test's quantiles):
    ``Q3(x) = erfc(sqrt(x/2)) + sqrt(2x/pi) exp(-x/2)`` solved for ``Q3(x) = erfc(sqrt(x1/2))``
    by bisection; beyond ``x1 = 600`` (tails below 1e-130) the asymptote ``x1 + 2 ln x1``."""
    if not x1 > 0.0:
        return 0.0
    if not math.isfinite(x1):
        return math.inf
    if x1 > 600.0:
        return x1 + 2.0 * math.log(x1)
    q1 = math.erfc(math.sqrt(0.5 * x1))

    def q3(x: float) -> float:
        return math.erfc(math.sqrt(0.5 * x)) + math.sqrt(2.0 * x / math.pi) * math.exp(-0.5 * x)

    lo, hi = x1, x1 + 4.0 * math.log(x1 + 2.0) + 10.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if q3(mid) > q1:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def fuse(
    pred: Pose, P: NDArray[np.float64], meas: Pose, R: NDArray[np.float64]
) -> tuple[Pose, NDArray[np.float64]]:
    """Information update of the prediction ``(pred, P)`` with the measurement ``(meas, R)``,
    written as the Kalman form ``K = P (P + R)^-1``, ``x+ = x + K v``, ``P+ = (I - K) P``
    (the same update, stable when ``R`` is huge along an axis). In floats."""
    Pl = P.tolist()
    Si = _inv3((P + R).tolist())
    if Si is None:
        return pred, P
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = Pl
    (i00, i01, i02), (_, i11, i12), (_, _, i22) = Si
    k00 = p00 * i00 + p01 * i01 + p02 * i02
    k01 = p00 * i01 + p01 * i11 + p02 * i12
    k02 = p00 * i02 + p01 * i12 + p02 * i22
    k10 = p01 * i00 + p11 * i01 + p12 * i02
    k11 = p01 * i01 + p11 * i11 + p12 * i12
    k12 = p01 * i02 + p11 * i12 + p12 * i22
    k20 = p02 * i00 + p12 * i01 + p22 * i02
    k21 = p02 * i01 + p12 * i11 + p22 * i12
    k22 = p02 * i02 + p12 * i12 + p22 * i22
    v0, v1, v2 = meas[0] - pred[0], meas[1] - pred[1], wrap_angle(meas[2] - pred[2])
    d0 = k00 * v0 + k01 * v1 + k02 * v2
    d1 = k10 * v0 + k11 * v1 + k12 * v2
    d2 = k20 * v0 + k21 * v1 + k22 * v2
    # (I - K) P, symmetric
    q00 = p00 - (k00 * p00 + k01 * p01 + k02 * p02)
    q01 = p01 - (k00 * p01 + k01 * p11 + k02 * p12)
    q02 = p02 - (k00 * p02 + k01 * p12 + k02 * p22)
    q11 = p11 - (k10 * p01 + k11 * p11 + k12 * p12)
    q12 = p12 - (k10 * p02 + k11 * p12 + k12 * p22)
    q22 = p22 - (k20 * p02 + k21 * p12 + k22 * p22)
    cov = np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
    return (pred[0] + d0, pred[1] + d1, wrap_angle(pred[2] + d2)), cov
