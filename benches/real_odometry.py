"""A per-step wheel-odometry error model fitted to real paired motions, and its use to
turn a reference (SLAM-corrected) path into realistic raw odometry.

The data: ``../shared/data/freiburg_course/odom_motions.dat`` (what the wheels said) and
``scanmatched_motions.dat`` (what scan matching said, taken as the truth), one relative
motion ``dx dy dtheta`` (robot frame of the step's start) per line, ~0.1 m per step.

The model, per step, for a true motion ``u = (dx, dy, dth)`` with length ``d = |(dx, dy)|``:

* systematic: ``odo_dx = (1 + scale) dx``, ``odo_dy = dy + skew dx``,
  ``odo_dth = (1 + turn_scale) dth + bias d`` (``bias``: heading bias, rad per metre);
* random: the residual of each real step divided by its predicted spread
  ``sigma_xy = a3 d + a4 |dth| + floor_xy`` / ``sigma_th = a1 |dth| + a2 d + floor_th``
  (AMCL-style alphas fitted to the absolute residuals), kept as a bank of real
  standardised errors (x, y, theta together, so their correlation and heavy tails stay
  real). Applying the model draws from that bank (seeded) and scales by the spread of the
  step at hand: the real errors, resampled.

The model is applied on sub-steps as long as the fitted steps (their median length, and
their 95th percentile of rotation), so the errors accumulate over a path the way they did
on the robot that recorded them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

#: steps turning at least this much (rad) set the rotation scale
TURNING = 0.01

__all__ = ["OdometryErrorModel", "apply_model", "fit_model", "load_motions", "relative_motions"]

@dataclass(frozen=True)
class OdometryErrorModel:
    scale: float  #: distance scale error (odo = (1 + scale) true)
    skew: float  #: lateral drift per metre forward
    turn_scale: float  #: rotation scale error
    bias: float  #: heading bias, rad per metre travelled
    a1: float  #: rotation noise per rad turned
    a2: float  #: rotation noise per metre travelled (rad/m)
    a3: float  #: translation noise per metre travelled
    a4: float  #: translation noise per rad turned (m/rad)
    floor_xy: float  #: translation noise of any moving step (m)
    floor_th: float  #: rotation noise of any moving step (rad)
    bank: tuple[tuple[float, float, float], ...] = ()  #: standardised real residuals
    step_m: float = 0.10  #: the fitted steps' median length: the model is applied on steps this long
    step_rad: float = 0.05  #: ... and at most this much rotation
    name: str = "fitted"

    def summary(self) -> dict[str, float | str | int]:
        d = asdict(self)
        d.pop("bank")
        d["bank_size"] = len(self.bank)
        d["bias_deg_per_m"] = math.degrees(self.bias)
        return d

    def worse(self, factor: float = 3.0, name: str = "bad") -> OdometryErrorModel:
        """A worse base: ``factor`` times the distance scale, skew and heading bias (at
        least 3 % and 1°/m, with the fitted signs), 1.5 times the rotation scale error
        (the fitted one is already large) and 1.5 times the noise."""

        def at_least(v: float, floor: float, k: float = factor) -> float:
            s = 1.0 if v >= 0 else -1.0
            return s * max(abs(v) * k, floor)

        return replace(
            self,
            scale=at_least(self.scale, 0.03),
            skew=self.skew * factor,
            turn_scale=at_least(self.turn_scale, 0.02, 1.5),
            bias=at_least(self.bias, math.radians(1.0)),
            a1=self.a1 * 1.5,
            a2=self.a2 * 1.5,
            a3=self.a3 * 1.5,
            a4=self.a4 * 1.5,
            floor_xy=self.floor_xy * 1.5,
            floor_th=self.floor_th * 1.5,
            name=name,
        )

    def spread(self, u: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        d = np.hypot(u[:, 0], u[:, 1])
        a = np.abs(u[:, 2])
        moving = (d > 1e-6) | (a > 1e-6)
        sxy = (self.a3 * d + self.a4 * a + self.floor_xy) * moving
        sth = (self.a1 * a + self.a2 * d + self.floor_th) * moving
        return sxy, sth

    def systematic(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        d = np.hypot(u[:, 0], u[:, 1])
        return np.column_stack(
            [
                (1.0 + self.scale) * u[:, 0],
                u[:, 1] + self.skew * u[:, 0],
                (1.0 + self.turn_scale) * u[:, 2] + self.bias * d,
            ]
        )


def load_motions(path: str | Path) -> NDArray[np.float64]:
    """An (N, 3) array of relative motions; a clear error naming the file otherwise."""
    try:
        m = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as e:
        raise ValueError(f"{path}: not a table of 'dx dy dtheta' rows ({e})") from None
    if m.shape[1] != 3:
        raise ValueError(f"{path}: expected 3 columns (dx dy dtheta), got {m.shape[1]}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{path}: non-finite values")
    return m


def _wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray((a + math.pi) % (2 * math.pi) - math.pi)


def fit_model(
    odom: NDArray[np.float64], truth: NDArray[np.float64], name: str = "fitted"
) -> OdometryErrorModel:
    """Fit the model to paired motions (odometry, truth), both (N, 3) robot-frame steps.

    Alternating, until the kept set settles: systematic terms by least squares (the rotation
    scale from the steps turning at least TURNING, the heading bias per metre from all the
    rest); spreads by least squares on the absolute residuals (E|N(0, s)| = s sqrt(2/pi));
    steps more than 5 spreads off dropped (a step where scan matching failed must not set the
    bias). The bank keeps every kept step's standardised error.
    """
    odom = np.asarray(odom, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    if odom.shape != truth.shape or odom.ndim != 2 or odom.shape[1] != 3:
        raise ValueError(f"paired motions must be two (N, 3) arrays, got {odom.shape} and {truth.shape}")
    d = np.hypot(truth[:, 0], truth[:, 1])
    a = np.abs(truth[:, 2])
    moving = (d > 1e-4) | (a > 1e-4)
    if moving.sum() < 20:
        raise ValueError(f"only {int(moving.sum())} moving steps: too few to fit an odometry model")
    o, t, d, a = odom[moving], truth[moving], d[moving], a[moving]
    eth_all = _wrap(o[:, 2] - t[:, 2])

    k = math.sqrt(math.pi / 2)
    keep = np.ones(len(t), dtype=bool)
    sxy = sth = np.ones(len(t))
    for _ in range(10):
        # systematic terms: ordinary least squares
        tx = t[keep, 0]
        scale = float(np.dot(tx, o[keep, 0]) / max(np.dot(tx, tx), 1e-12)) - 1.0
        skew = float(np.dot(tx, o[keep, 1] - t[keep, 1]) / max(np.dot(tx, tx), 1e-12))
        # rotation scale from the turning steps only (|dth| >= TURNING): on near-straight
        # steps the rotation is mostly quantisation and would set the scale; then the
        # heading bias per metre from every step with that scale
        turning = keep & (a >= TURNING)
        tt = t[turning, 2]
        turn_scale = float(np.dot(tt, eth_all[turning]) / max(np.dot(tt, tt), 1e-12)) if turning.sum() >= 5 else 0.0
        rest = eth_all[keep] - turn_scale * t[keep, 2]
        bias = float(np.sum(rest) / max(np.sum(d[keep]), 1e-12))
        rx = o[:, 0] - (1 + scale) * t[:, 0]
        ry = o[:, 1] - t[:, 1] - skew * t[:, 0]
        rth = eth_all - turn_scale * t[:, 2] - bias * d
        # spreads: least squares on the absolute residuals (E|N(0, s)| = s sqrt(2/pi))
        ones = np.ones(int(keep.sum()))
        Axy = np.column_stack([d[keep], a[keep], ones])
        cxy, *_ = np.linalg.lstsq(Axy, k * 0.5 * (np.abs(rx[keep]) + np.abs(ry[keep])), rcond=None)
        Ath = np.column_stack([a[keep], d[keep], ones])
        cth, *_ = np.linalg.lstsq(Ath, k * np.abs(rth[keep]), rcond=None)
        a3, a4, fxy = (float(v) for v in np.maximum(cxy, 0.0))
        a1, a2, fth = (float(v) for v in np.maximum(cth, 0.0))
        fxy = max(fxy, 1e-5)
        fth = max(fth, 1e-6)
        sxy = a3 * d + a4 * a + fxy
        sth = a1 * a + a2 * d + fth
        # trim steps more than 5 spreads off (a step where scan matching failed)
        new_keep = (np.abs(rx) <= 5 * sxy) & (np.abs(ry) <= 5 * sxy) & (np.abs(rth) <= 5 * sth)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    model = OdometryErrorModel(
        scale=scale, skew=skew, turn_scale=turn_scale, bias=bias,
        a1=a1, a2=a2, a3=a3, a4=a4, floor_xy=fxy, floor_th=fth, name=name,
        step_m=float(max(np.median(d[keep]), 0.01)),
        step_rad=float(max(np.percentile(a[keep], 95), 0.005)),
    )  # fmt: skip
    sxy, sth = model.spread(t[keep])
    bank = np.column_stack([rx[keep] / sxy, ry[keep] / sxy, rth[keep] / sth])
    return replace(model, bank=tuple(tuple(float(v) for v in row) for row in bank))


def relative_motions(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Robot-frame steps between consecutive (N, 3) poses: (N-1, 3)."""
    p = np.asarray(poses, dtype=np.float64)
    dx = p[1:, 0] - p[:-1, 0]
    dy = p[1:, 1] - p[:-1, 1]
    c, s = np.cos(p[:-1, 2]), np.sin(p[:-1, 2])
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, _wrap(p[1:, 2] - p[:-1, 2])])


def _substeps(
    poses: NDArray[np.float64], step_m: float, step_rad: float
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The path cut into sub-steps of at most step_m / step_rad (linear in x, y and
    unwrapped heading); returns the sub-step motions and, per input pose, the index of the
    sub-step pose it lands on."""
    p = np.asarray(poses, dtype=np.float64).copy()
    p[:, 2] = np.unwrap(p[:, 2])
    seg = np.diff(p, axis=0)
    n = np.maximum(
        1,
        np.ceil(np.maximum(np.hypot(seg[:, 0], seg[:, 1]) / step_m, np.abs(seg[:, 2]) / step_rad)),
    ).astype(np.int64)
    start = np.repeat(np.arange(len(seg)), n)
    frac = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 1) / np.repeat(n, n)
    fine = np.vstack([p[:1], p[start] + seg[start] * frac[:, None]])
    land = np.concatenate([[0], np.cumsum(n)])
    return relative_motions(fine), land


def compose_steps(start: NDArray[np.float64], steps: NDArray[np.float64]) -> NDArray[np.float64]:
    """Integrate robot-frame steps from ``start``: (N+1, 3) poses."""
    out = np.empty((len(steps) + 1, 3))
    out[0] = start
    x, y, th = (float(v) for v in start)
    for i, (dx, dy, dth) in enumerate(steps):
        c, s = math.cos(th), math.sin(th)
        x += c * dx - s * dy
        y += s * dx + c * dy
        th = math.remainder(th + dth, 2 * math.pi)
        out[i + 1] = (x, y, th)
    return out


def apply_model(
    model: OdometryErrorModel, reference: NDArray[np.float64], seed: int
) -> NDArray[np.float64]:
    """Raw odometry poses, one per reference pose, starting at the first reference pose:
    the reference motion with the model's systematic and resampled random errors."""
    ref = np.asarray(reference, dtype=np.float64)
    if len(ref) < 2:
        return ref.copy()
    steps, land = _substeps(ref, model.step_m, model.step_rad)
    rng = np.random.default_rng(seed)
    noisy = model.systematic(steps)
    sxy, sth = model.spread(steps)
    if model.bank:
        bank = np.asarray(model.bank)
        z = bank[rng.integers(0, len(bank), size=len(steps))]
    else:
        z = rng.standard_normal((len(steps), 3))
    noisy[:, 0] += z[:, 0] * sxy
    noisy[:, 1] += z[:, 1] * sxy
    noisy[:, 2] += z[:, 2] * sth
    return compose_steps(ref[0], noisy)[land]
