"""Is a pose right? The evidence a scan gives at one pose, and the map's quality it is read against.

:class:`MapQuality` holds what the localizer's thresholds follow from: the map's resolution
(a grid's cell size; for other maps the spacing of its samples) and the residual its scan
fits really show (a running median of the ICP's RMS over the verified fits and those the
odometry agrees with, see :class:`MapQuality`). :attr:`MapQuality.sigma` is the
per-beam residual to expect; the ICP's correspondence distance and robust scale, the scan
covariance's noise floor and the verification's hit distance are all multiples of it.

:class:`FitChecker` scores a pose against the scan:

* ``hit``: the share of beams that end on a mapped wall (within the hit distance);
* ``see_through`` (optional, see :class:`FitChecker`): the share of beams that pass
  **through** a mapped wall before their return — impossible at the right pose on an exact
  map (people and clutter only shorten beams), e.g. a pose slid past a corridor's end wall;
* ``rms``: the residual of the beams that hit, against the expected ``sigma``.

A beam's crossing is looked for on a raster of the map at its resolution, sampled along the
beam from the sensor up to a margin before its return; the margin grows at grazing
incidence (a beam running along a wall stays within a cell of it for a while).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from icploc import _core
from icploc.median import median
from icploc.se2 import Pose

if TYPE_CHECKING:
    from icploc.config import LocalizerConfig

__all__ = ["FitCheck", "FitChecker", "MapQuality"]


@dataclass(frozen=True)
class FitCheck:
    """The evidence of one scan at one pose."""

    hit: float  #: share of beams ending on a mapped wall
    see_through: float  #: share of beams crossing a mapped wall before their return
    rms: float  #: RMS point-to-line residual of the beams that hit (m)
    beams: int  #: beams checked


#: a median residual this many priors or more counts after ``loosen_after`` fits
_LOOSEN_EARLY = 2.0


class MapQuality:
    """The map's resolution and the residual its fits show (see the module docstring).

    What it learns from (the localizer feeds it):

    * :meth:`observe`: a verified fit; its residual, hit share and see-through share;
    * :meth:`observe_consistent`: a fit the odometry agrees with (chi-square accepted) that
      verification turned down; its residual when at least ``rms_min_hit`` of the beams end
      on walls (a wrong place's fits must not loosen the verification), its hit share only
      when at least ``hit_floor`` do (the verification's absolute floor).

    The residual of consistent fits counts because on a grid from another, sparse pass
    the scan's walls sit 4-6 cm from the map's and the right pose's fits do not verify
    while the expected residual is the prior's: learning it from verified fits alone (whose
    beams are within the hit distance already) never finds out. It is capped at
    ``max(2 x prior, sigma_cap)`` (the localizer passes half the ICP's final correspondence
    distance floor). The hit share of consistent fits below the floor does not count: right
    fits that half verify would teach the usual share downwards, the relative bar would
    follow it, and a wrong fit hitting as little would verify (csail 5 cm, biased odometry:
    a fit 24 cm off at a hit share of 0.28 was fused).

    ``learn_after``: fits before the residual counts as measured (the prior until then);
    ``loosen_after``: fits before a median above twice the prior (the old cap) counts
    already. A map whose fits show that much more than the prior (walls from another pass)
    is found out within a few fits, before the prior's hit distance leaves every right pose
    unverified and the pose is lost with nothing learned (acapulco 5 cm, biased odometry:
    lost on its 14th scan); a residual nearer the prior, or below it, waits for
    ``learn_after`` fits (aces 10 cm: a median 1.2-1.5 x the prior taken after 3 fits
    widened the ICP's correspondences early and a fit 41 cm off followed).
    """

    def __init__(
        self,
        resolution: float,
        *,
        window: int,
        sigma_cap: float,
        hit_floor: float,
        rms_min_hit: float,
        learn_after: int,
        loosen_after: int,
        unmeasured_hit: float = 0.0,
    ) -> None:
        if not (resolution > 0 and math.isfinite(resolution)):
            raise ValueError(f"MapQuality: resolution must be positive, got {resolution!r}")
        if not (sigma_cap >= 0 and math.isfinite(sigma_cap)):
            raise ValueError(f"MapQuality: sigma_cap must be >= 0, got {sigma_cap!r}")
        if not 0.0 <= hit_floor <= 1.0:
            raise ValueError(f"MapQuality: hit_floor must be in [0, 1], got {hit_floor!r}")
        if not 0.0 <= rms_min_hit <= 1.0:
            raise ValueError(f"MapQuality: rms_min_hit must be in [0, 1], got {rms_min_hit!r}")
        if not 1 <= loosen_after <= learn_after <= window:
            raise ValueError(
                "MapQuality: need 1 <= loosen_after <= learn_after <= window, got "
                f"{loosen_after!r}, {learn_after!r}, {window!r}"
            )
        self.resolution = float(resolution)
        #: a prior for the per-beam residual: a cell's quantisation (res / sqrt 12) and a
        #: scanner's centimetre, together
        self.prior = math.hypot(self.resolution / math.sqrt(12.0), 0.01)
        #: the learned residual's ceiling
        self.sigma_max = max(2.0 * self.prior, float(sigma_cap))
        self.hit_floor = float(hit_floor)
        #: until the usual share is measured, the share a fit must show to teach it
        self.unmeasured_hit = float(unmeasured_hit)
        self.rms_min_hit = float(rms_min_hit)
        self.learn_after = int(learn_after)
        self.loosen_after = int(loosen_after)
        self._measured = False
        self._rms: deque[float] = deque(maxlen=window)
        self._hit: deque[float] = deque(maxlen=window)
        self._see: deque[float] = deque(maxlen=window)
        self._vhit: deque[float] = deque(maxlen=window)
        self._n = 0
        self._sigma = self.prior
        self._hit_ref = 1.0
        self._vhit_ref = 1.0
        self._see_ref = 0.0

    @classmethod
    def from_config(cls, resolution: float, config: LocalizerConfig | None = None) -> MapQuality:
        """The map quality the localizer learns with ``config`` (default: the default
        config): its ``localizer.quality_*`` settings; the residual's ceiling a fraction of
        ``icp.min_correspondence_distance``, the hit share's floor ``verify_min_hit_ratio``
        and the residual's one a fraction of it."""
        if config is None:
            from icploc.config import LocalizerConfig

            config = LocalizerConfig()
        lc = config.localizer
        return cls(
            resolution,
            window=lc.quality_window,
            sigma_cap=lc.quality_sigma_cap * config.icp.min_correspondence_distance,
            hit_floor=lc.verify_min_hit_ratio,
            unmeasured_hit=lc.verify_unmeasured_hit_ratio,
            rms_min_hit=lc.quality_rms_min_hit * lc.verify_min_hit_ratio,
            learn_after=lc.quality_learn_after,
            loosen_after=lc.quality_loosen_after,
        )

    def observe(self, check: FitCheck, rms: float | None = None) -> None:
        """Learn from a verified fit; ``rms``: the ICP's own residual (else ``check.rms``)."""
        self._observe_rms(check.rms if rms is None else rms)
        self._hit.append(check.hit)
        self._vhit.append(check.hit)
        self._see.append(check.see_through)
        self._count()

    def observe_consistent(self, check: FitCheck, rms: float | None = None) -> None:
        """Learn from a fit the odometry agrees with (chi-square accepted) that verification
        turned down: its residual (``rms``, the ICP's own, else ``check.rms``) when its hit
        share is at least ``rms_min_hit``, and its hit share when it is at least
        ``hit_floor``. Learning the share from verified fits alone ratchets: only shares
        above the threshold are ever seen, so one well-mapped start (a reference near 1)
        would keep every later fit unverified."""
        if check.hit >= self.rms_min_hit:
            self._observe_rms(check.rms if rms is None else rms)
        floor = self.hit_floor if self.hit_measured else max(self.hit_floor, self.unmeasured_hit)
        if check.hit >= floor:
            self._hit.append(check.hit)
        self._count()

    def _observe_rms(self, rms: float) -> None:
        if math.isfinite(rms):
            self._rms.append(rms)

    def _count(self) -> None:
        self._n += 1
        if self._n % 5 == 0 or len(self._rms) < self.learn_after:  # medians every 5 fits
            self._refresh()

    def _refresh(self) -> None:
        n = len(self._rms)
        m = median(self._rms) if n >= self.loosen_after else self.prior
        # early only when the prior is clearly too tight (beyond the old cap of twice it)
        early = n >= self.loosen_after and m > _LOOSEN_EARLY * self.prior
        # once measured it stays so (later tighter fits lower the median, not the state: a
        # flip back to the prior would unverify the right poses again)
        self._measured = self._measured or n >= self.learn_after or early
        self._sigma = (
            min(max(m, 0.5 * self.prior), self.sigma_max) if self._measured else self.prior
        )
        self._hit_ref = median(self._hit) if len(self._hit) >= 5 else 1.0
        self._see_ref = median(self._see) if len(self._see) >= 5 else 0.0
        self._vhit_ref = median(self._vhit) if len(self._vhit) >= 5 else 1.0

    @property
    def measured(self) -> bool:
        """The residual is the fits' (see ``learn_after``, ``loosen_after``), not the prior."""
        return self._measured

    @property
    def sigma(self) -> float:
        """The per-beam residual to expect (m): measured once there are enough fits (their
        median), never below half the prior nor above :attr:`sigma_max` (one bad stretch
        must not loosen every threshold)."""
        return self._sigma

    @property
    def hit_measured(self) -> bool:
        """The usual hit share has been measured (at least 5 fits), not assumed."""
        return len(self._hit) >= 5

    @property
    def hit_reference(self) -> float:
        """The typical hit share of the fits learned from (verified ones, and consistent
        ones with at least ``hit_floor`` of their beams on walls); 1 before five."""
        return self._hit_ref

    @property
    def verified_hit_reference(self) -> float:
        """The typical hit share of verified fits alone (1 before five): what "far fewer
        beams than usual" is read against (consistent fits that did not verify do not
        lower it)."""
        return self._vhit_ref

    @property
    def see_through_reference(self) -> float:
        return self._see_ref

    def hit_distance(self) -> float:
        """A beam within this of the map (m) ends on a wall."""
        return 3.0 * self.sigma + 0.5 * self.resolution


#: the see-through check's map: its points, their normals, the raster's origin and the
#: occupancy raster at the map's resolution
_Raster = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]


class FitChecker:
    """Scores poses on one map (see the module docstring). ``points`` are the map's sample
    points (the ICP index's), ``normals`` their unit normals."""

    def __init__(
        self,
        index: _core.MapIndex,
        quality: MapQuality,
        max_beams: int = 120,
        see_through: bool = False,
    ) -> None:
        self.index = index
        self.quality = quality
        self.max_beams = int(max_beams)
        #: look for beams crossing mapped walls (off by default: on real map_server grids
        #: built from a run, walls are bands 3-10 cells thick whose near face lies in front
        #: of the returns, and people leave specks in corridors; at the right pose 40 % of
        #: the beams of the Freiburg 079 grid "cross" a wall, 50-64 % at 0.5-1 m off: no
        #: margin to decide on. It costs ~0.3 ms a check.)
        self.see_through = bool(see_through)
        self._cell = quality.resolution
        self._subsample: dict[int, NDArray[np.int64]] = {}
        #: the see-through check's inputs, built on its first use
        self._raster: _Raster | None = None

    def _see_through_raster(self) -> _Raster:
        """(map points, their normals, the raster's origin, the occupancy raster at the
        map's resolution)."""
        if self._raster is None:
            pts = np.asarray(self.index.points, dtype=np.float64)
            normals = np.asarray(self.index.normals, dtype=np.float64)
            cell = self._cell
            lo = pts.min(axis=0) - 2 * cell
            hi = pts.max(axis=0) + 2 * cell
            shape = (
                int(math.ceil((hi[1] - lo[1]) / cell)) + 1,
                int(math.ceil((hi[0] - lo[0]) / cell)) + 1,
            )
            occ = np.zeros(shape, dtype=bool)
            ij = np.floor((pts - lo) / cell).astype(np.int64)
            occ[ij[:, 1], ij[:, 0]] = True
            self._raster = (pts, normals, lo, occ)
        return self._raster

    def check(self, points: NDArray[np.float64], pose: Pose) -> FitCheck:
        """The evidence of the scan ``points`` (robot frame, (N, 2)) at ``pose``: at most
        ``max_beams`` beams spread evenly over the scan, each a hit when its nearest map
        point is within the hit distance, the residual of a hit its offset from that point
        along the point's normal (point-to-line, as the ICP measures it). The hit share and
        residual are the core's (``icploc._core.fit_score``), one call."""
        n = points.shape[0]
        if n == 0:
            return FitCheck(0.0, 0.0, math.inf, 0)
        hd = self.quality.hit_distance()
        if not self.see_through:
            hit, rms, beams = _core.fit_score(self.index, points, pose, self.max_beams, hd)
            return FitCheck(hit, 0.0, rms, beams)
        map_points, normals, lo, occ_map = self._see_through_raster()
        if n > self.max_beams:
            k = self._subsample.get(n)
            if k is None:
                k = self._subsample[n] = (
                    np.linspace(0, n - 1, self.max_beams).round().astype(np.int64)
                )
            points = points[k]
            n = points.shape[0]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        wx = pose[0] + c * points[:, 0] - s * points[:, 1]
        wy = pose[1] + s * points[:, 0] + c * points[:, 1]
        world = np.column_stack((wx, wy))
        d, j = self.index.nearest(world)
        hits = d < hd
        nh = int(hits.sum())
        nrm = normals[j]
        if nh:
            mp = map_points[j[hits]]
            r = (wx[hits] - mp[:, 0]) * nrm[hits, 0] + (wy[hits] - mp[:, 1]) * nrm[hits, 1]
            rms = float(np.sqrt(np.mean(r * r)))
        else:
            rms = math.inf
        # see-through: sample each beam from the sensor up to a margin before its return
        ox, oy = pose[0], pose[1]
        vx, vy = wx - ox, wy - oy
        rng = np.hypot(vx, vy)
        ux, uy = vx / np.maximum(rng, 1e-9), vy / np.maximum(rng, 1e-9)
        inc = np.abs(ux * nrm[:, 0] + uy * nrm[:, 1])
        inc = np.where(hits, np.maximum(inc, 0.15), 1.0)
        cell = self._cell
        margin = 2.0 * cell / inc + hd
        reach = rng - margin
        step = 0.5 * cell
        m = int(math.ceil(float(reach.max(initial=0.0)) / step))
        if m <= 0:
            return FitCheck(nh / n, 0.0, rms, n)
        t = (np.arange(m) + 1.0) * step  # from half a cell out
        sx = ox + ux[:, None] * t[None, :]
        sy = oy + uy[:, None] * t[None, :]
        valid = t[None, :] < reach[:, None]
        ix = np.floor((sx - lo[0]) / cell).astype(np.int64)
        iy = np.floor((sy - lo[1]) / cell).astype(np.int64)
        h, w = occ_map.shape
        inside = valid & (ix >= 0) & (iy >= 0) & (ix < w) & (iy < h)
        occ = np.zeros_like(inside)
        occ[inside] = occ_map[iy[inside], ix[inside]]
        # a crossing is a run of occupied samples at least a cell long: a wall, not the
        # speck a person left in the map
        run = occ[:, 1:] & occ[:, :-1]
        crossed = run.any(axis=1)
        return FitCheck(nh / n, float(crossed.mean()), rms, n)
