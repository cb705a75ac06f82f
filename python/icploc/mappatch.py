"""Where the map is missing: a map_server grid of what the laser saw outside the map.

:class:`icploc.outside.OutsideMonitor` (with ``record=True``) keeps, for every stretch
outside the map, the scans' points and the poses they were coasted at, up to the scan
that locked again. Dead reckoning drifts; the lock says by how much at the stretch's end.
:func:`corrected_poses` spreads that correction along the stretch: the heading error in
proportion to the motion of each step (re-integrating the odometry steps), then the
remaining position error in proportion to the motion done so far — exact at the exit (a
verified pose) and at the lock. :func:`patch_grid` ray-casts the scans at those poses
(free space along each beam, hits at its end; :func:`icploc.maps.build.build_grid`'s rules)
into a grid aligned with the map's cells, :func:`write_patch` writes it as YAML + PGM.
``icploc map merge`` (:mod:`icploc.maps.merge`) puts it into the map.

Before the correction the coasted chain is tightened by matching each scan against the
stretch's own previous scans (:func:`refined_poses`; never against the map, whose walls
are not there): the odometry steps become scan-matched steps where the walls allow.
The patch's poses then come from a least-squares pose graph (:func:`graph_poses`): those
chain steps, keyframe scans matched against the stretch's earlier keyframes nearby (the
wing toured, the corridor driven back), the exit and the lock as priors; heading included;
one odometry scale for the whole stretch (:class:`_Scale`); and, with :class:`MappedWalls`,
each scan's beams that end on mapped walls matched against them (the stretch's ends tied
to the map). Each stretch back in the map is also placed by its own scans alone
(:func:`submap_poses`: sequential scan-to-submap ICP from the exit, the loop error at the
lock spread along it); that placement replaces the graph's where it verifies
(:func:`_submap_or_graph`, :func:`self_consistency`), and the patch's YAML says per
stretch which was used and why. The grid is thinned (:data:`PATCH_PEAK_SHARE`): a wall's
faint fringe goes.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from icploc.se2 import Pose, between, compose, wrap_angle

if TYPE_CHECKING:
    from icploc.maps.build import BuiltGrid
    from icploc.outside import Stretch

__all__ = [
    "PATCH_PEAK_RADIUS",
    "PATCH_PEAK_SHARE",
    "PATCH_RESOLUTION",
    "PATCH_SIGMA_BOUND",
    "PATCH_SIGMA_NONE",
    "PATCH_SIGMA_UNIT",
    "MappedWalls",
    "cell_sigmas",
    "chain_heading_errors",
    "confidence_record",
    "corrected_poses",
    "graph_poses",
    "graph_solution",
    "grid_from_scans",
    "in_patch",
    "patch_grid",
    "patch_record",
    "patch_solution",
    "read_sigma_image",
    "refined_poses",
    "sigma_image",
    "sigma_path",
    "submap_poses",
    "self_consistency",
    "SubmapRefinement",
    "wall_sigmas",
    "write_patch",
]

#: cell size of a patch for a map without a grid [m] (a grid map's own resolution otherwise)
PATCH_RESOLUTION = 0.05
#: a patch's occupied cell needs at least this share of the hits of the most hit cell
#: within one cell of it: a patch's poses are surer than dead reckoning, not than a
#: map's, so a wall seen from a few of them is drawn a cell thick with a faint fringe
#: (simulated wing, seed 1: the fringe was 107 of the 2556 wall cells, all of those more
#: than 10 cm off, with at most 8 % of their neighbour's hits)
PATCH_PEAK_SHARE = 0.25
#: how far from a cell :data:`PATCH_PEAK_SHARE` looks for the most hit cell [m] (at
#: least one cell): the fringe a few centimetres of pose error put beside a wall (at
#: 5 cm cells two cells: simulated wing, seeds 2 and 4, a pillar's face drawn twice,
#: 12.5 cm behind itself, by 2-3 beams near the laser's range from the corridor, the
#: face itself two cells away; at 10 cm cells one cell, as before)
PATCH_PEAK_RADIUS = 0.1
#: a scan match's direction held by fewer beams than this (the smallest eigenvalue of the
#: fit's translational information, :func:`icploc.fusion.scan_covariance`) is no
#: measurement: a loop match's always, a chain step's when the step is shorter than the
#: keyframe spacing (scans centimetres apart: the match along a wall sticks to its guess;
#: simulated wing, the corridor's chain 1.4 % short, the wing's east wall 1 %). On the
#: real logs' 0.5 m steps the few beams along a corridor are what holds it (belgioioso's
#: patch 68 -> 40 % within 10 cm without them), so a long step keeps them.
WEAK_AXIS_BEAMS = 20.0
#: a patch's wall cell is *confident* when the sigma of where its walls are drawn (along
#: their normal, from the pose graph's marginal covariance of the scans that drew it:
#: :func:`cell_sigmas`) is at most this [m]: half the 10 cm a patch's walls should lie
#: within, so a confident wall is drawn within it at 2 sigma
PATCH_SIGMA_BOUND = 0.05
#: the sigma image's unit [m per grey level] (``<patch>.sigma.pgm``: 0..254, 255 where no
#: beam ended or no pose covariance says how sure the cell is)
PATCH_SIGMA_UNIT = 0.002
#: the sigma image's grey level for "no sigma" (no beam end, or no pose covariance); a
#: finite sigma is written one level below at most (0.508 m and more)
PATCH_SIGMA_NONE = 255
#: how many nodes of a stretch's pose graph get their own marginal covariance
#: (:func:`_marginals`; three back-solves each against the whole factorization: all of a
#: 5000-scan stretch's took 89 s); the others take the nearest computed node's
MARGINAL_NODES = 200
#: the keyframe spacing of a stretch's pose graph: scans this far apart (metres travelled,
#: or radians turned: :data:`KEYFRAME_TURN`) are the loop matches' keyframes, and a chain
#: step within both is a *short* step (:data:`WEAK_AXIS_BEAMS`)
KEYFRAME_STEP = 0.25
#: the turn that makes a keyframe by itself [rad] (see :data:`KEYFRAME_STEP`)
KEYFRAME_TURN = 0.3


#: the chain's reference scans are at least this far apart [m] (or
#: :data:`CHAIN_REF_TURN` turned): a scan closer to the newest one is matched but not kept.
#: 0: the previous ``keep`` scans. 0.2 m / 0.1 rad (the simulated scans 4 cm apart: the
#: references reach about 1 m back, so a match's own heading error and the odometry's are
#: spread over more steps) takes the chain's heading error at the lock from -1.8..-3.8 to
#: -0.4..-2.3 deg (seeds 0-9), but moves which seeds' walls fail, not how many: seeds 0-9
#: 100 / 100 / 100 / 100 / 100 / 99.9 / 94.9 / 96.9 / 92.9 / 76.2 % within 10 cm (now
#: 100 / 95.3 / 100 / 100 / 100 / 99.3 / 92.1 / 100 / 100 / 99.3); the real logs' 0.5 m
#: steps are not affected (aces, belgioioso, csail: the same patches)
CHAIN_REF_STEP = 0.0
#: (see :data:`CHAIN_REF_STEP`) [rad]
CHAIN_REF_TURN = 0.0
#: the independent beams a chain step's scan match counts as (its covariance:
#: :func:`icploc.fusion.scan_covariance`). With the odometry's heading sigma
#: (:data:`CHAIN_ODOM_HEADING`) it sets how much of the odometry's heading drift the chain
#: keeps (simulated wing, seeds 0-9: the localizer's odometry -1.9..-11.5 deg at the lock,
#: the chain +0.3..-3.8 deg). 50 instead: the chain +0.1..+1.9 deg (the matches' own
#: +0.001..+0.008 deg per match then shows), seeds 0-9 100 / 100 / 100 / 94.5 / 99.4 /
#: 99.4 / 97.2 / 99.2 / 99.8 / 80.1 % within 10 cm
CHAIN_BEAMS = 5.0
#: a chain step's odometry heading sigma (rad, plus rad per metre or radian of the step);
#: 0.01 + 0.1 instead: seeds 0-9 100 / 100 / 100 / 100 / 100 / 99.3 / 95.3 / 86.5 / 99.4 /
#: 89.8 %; with the references 0.2 m apart as well (:data:`CHAIN_REF_STEP`), the chain
#: within 1.5 deg at the lock, seeds 0-5 100 / 87.3 / 87.2 / 100 / 100 / 100 %
CHAIN_ODOM_HEADING = (0.003, 0.03)
#: how far back along its way [m travelled, plus 0.3 m per radian turned] each keyframe of
#: a stretch's pose graph is matched, pairwise, against the keyframes before it, for the
#: heading (:func:`_sequence_edges`; 0: none). A chain step is the odometry step fused with
#: a match against the previous few scans, the two about as sure of the heading (0.24 /
#: 0.29 deg at 4 cm), so the chain's heading random-walks with the odometry's and keeps a
#: share of its bias (the simulated wheels: several degrees over the wing); a match over
#: metres is as sure as one over centimetres, so over such a baseline the matches win.
#: Simulated wing (seeds 6 / 13, the tuned set): 1 m 95.5 / 100 %, 2 m 100 / 100 %, 4 m
#: 100 / 100 % of the walls within 10 cm (without: 92.1 / 90.1 %)
SEQUENCE_REACH = 2.0
#: a mapped wall's prior on a stretch's pose (:class:`MappedWalls`) that the solved graph
#: disagrees with by a chi-square above this times the prior's degrees of freedom (the
#: numerical rank of its information, :func:`_prior_dof`: 2 where the match left a wall's
#: length free, 3 otherwise), but within the outlier gate, has its information scaled by
#: that bound over its chi-square and the graph is solved once more
#: (:func:`_wall_prior_solve`): a prior off by a few sigma (a wall matched a few
#: centimetres beside itself, seen from far or along it) pulls its stretch less. Per degree
#: of freedom, so a full-rank prior is not held to a one-direction prior's bound. What a
#: right prior's chi-square looks like at the solution (30 simulated seeds, 6032 kept
#: priors: 87 % rank 2, 13 % rank 3, none rank 1): far below its distribution's, median
#: 0.03 / 0.10, 99th percentile 0.8 / 1.2 (rank 2 / 3), since the priors of neighbouring
#: scans see the same walls and the solve fits them together; 0.2 % exceed 3 and those are
#: 5-15 cm off. 1.5 keeps the rank-2 bound at the 3 it was measured with (the chi-square
#: 0.9 quantile per dof instead, 4.61 / 6.25, scaled seed 10's wrong prior less: 96.7 ->
#: 95.7 % of its walls within 10 cm). 0: none
WALL_PRIOR_CHI2_PER_DOF = 1.5
#: a direction of a wall prior's information below this share of its largest eigenvalue is
#: one the match did not constrain (:func:`icploc.fusion.scan_covariance` gives it about
#: 1e-6, against 1e1-3e5 for a held one: measured shares below 1e-10 or above 1e-4)
WALL_PRIOR_RANK_TOL = 1e-6


def _apart(u: Pose, step: float = KEYFRAME_STEP, turn: float = KEYFRAME_TURN) -> bool:
    """Whether a motion ``u`` (a relative pose) spans the keyframe spacing: at least
    ``step`` m travelled or ``turn`` rad turned. The one measure of the loop matches'
    keyframes and of a chain's short steps."""
    return math.hypot(u[0], u[1]) >= step or abs(wrap_angle(u[2])) >= turn


def corrected_poses(
    start: Pose,
    coasted: Sequence[Pose],
    dead_reckoned_end: Pose,
    lock: Pose,
    trust: Sequence[float] | None = None,
) -> NDArray[np.float64]:
    """The coasted poses of a stretch corrected so its last pose is ``lock``.

    ``start`` is the verified pose before the stretch, ``coasted`` the stretch's poses
    (the last may already be the lock: ``dead_reckoned_end`` is what dead reckoning said
    there). Each odometry step gets a share of the heading error (its length plus a tenth
    of its turn, over the stretch's), the position error left then is spread by the motion
    done so far. ``trust`` (per step, 0..1; default 0): a step's share is scaled by
    ``1 - 0.9 trust`` (a scan-matched step drifts far less than an odometry one).
    Returns (N, 3)."""
    pts = [tuple(map(float, p)) for p in coasted]
    if not pts:
        return np.zeros((0, 3))
    pts[-1] = tuple(map(float, dead_reckoned_end))
    steps = [between(a, b) for a, b in zip([start, *pts[:-1]], pts, strict=True)]
    w = np.array([math.hypot(u[0], u[1]) + 0.1 * abs(u[2]) for u in steps]) + 1e-9
    if trust is not None:
        w *= 1.0 - 0.9 * np.clip(np.asarray(trust, dtype=np.float64), 0.0, 1.0)
    w /= w.sum()
    e_th = wrap_angle(lock[2] - pts[-1][2])
    out = np.zeros((len(pts), 3))
    p: Pose = (float(start[0]), float(start[1]), float(start[2]))
    for i, u in enumerate(steps):
        p = compose(p, (u[0], u[1], u[2] + e_th * float(w[i])))
        out[i] = p
    r = np.array([lock[0] - out[-1, 0], lock[1] - out[-1, 1]])
    out[:, :2] += np.cumsum(w)[:, None] * r
    out[:, 2] = np.angle(np.exp(1j * out[:, 2]))
    return out


def refined_poses(
    start: Pose,
    scans: Sequence[NDArray[np.float64]],
    coasted: Sequence[Pose],
    *,
    keep: int = 5,
    min_inliers: float = 0.6,
    gate: float = 16.0,
) -> tuple[list[Pose], list[float]]:
    """The coasted poses re-chained by matching each scan against the stretch's own
    previous ``keep`` scans (never the map). Each odometry step (its noise growing with
    its length) is fused with the scan match (its covariance from the fit: a corridor
    says nothing along itself) when the match converged, explains ``min_inliers`` of the
    scan and agrees with the odometry within the chi-square ``gate``; otherwise the
    odometry step stands. The drift left is small where walls constrain the scans; the
    lock's correction then spreads it. Returns the poses and per step how much the scan
    match tightened it (0: odometry alone .. 1)."""
    poses, trust, _ = _chain(start, scans, coasted, keep=keep, min_inliers=min_inliers, gate=gate)
    return poses, trust


def _chain(
    start: Pose,
    scans: Sequence[NDArray[np.float64]],
    coasted: Sequence[Pose],
    *,
    keep: int = 5,
    min_inliers: float = 0.6,
    gate: float = 16.0,
    weak_axis_beams: float = WEAK_AXIS_BEAMS,
    keyframe_step: float = KEYFRAME_STEP,
    exit_motion: Any = None,
) -> tuple[list[Pose], list[float], list[NDArray[np.float64]]]:
    """:func:`refined_poses` and per step its covariance (map frame). A step within the
    keyframe spacing (:func:`_apart`: under ``keyframe_step`` m and :data:`KEYFRAME_TURN`)
    leaves a direction its match holds by fewer than ``weak_axis_beams`` beams to the
    odometry (:data:`WEAK_AXIS_BEAMS`). The first step's heading sigma is the odometry's
    own (:func:`_exit_step_heading_sigma`, ``exit_motion``)."""
    from icploc._core import IcpError, MapIndex, icp
    from icploc.fusion import fuse, mahalanobis2, scan_covariance

    cfg = _chain_config()
    out: list[Pose] = []
    trust: list[float] = []
    covs: list[NDArray[np.float64]] = []
    prev: Pose = (float(start[0]), float(start[1]), float(start[2]))
    prev_c: Pose = prev
    world: list[NDArray[np.float64]] = []
    kept: Pose | None = None  # the pose of the newest reference scan
    normals: list[NDArray[np.float64]] = []
    for pts, c in zip(scans, coasted, strict=True):
        c = (float(c[0]), float(c[1]), float(c[2]))
        u = between(prev_c, c)
        guess = compose(prev, u)
        pose, t = guess, 0.0
        step = math.hypot(u[0], u[1]) + 0.3 * abs(u[2])
        sxy = 0.01 + 0.02 * step
        sth = CHAIN_ODOM_HEADING[0] + CHAIN_ODOM_HEADING[1] * step
        if not out:
            sth = _exit_step_heading_sigma(u, exit_motion)
        P = np.diag([sxy * sxy, sxy * sxy, sth * sth])
        cov = P
        if world and pts.shape[0] >= 20:
            try:
                res = icp(
                    pts, MapIndex(np.concatenate(world), np.concatenate(normals), None), guess, cfg
                )
            except IcpError:
                res = None
            if res is not None and res.converged and res.inlier_ratio >= min_inliers:
                z = (float(res.pose[0]), float(res.pose[1]), float(res.pose[2]))
                weak = 0.0 if _apart(u, keyframe_step) else weak_axis_beams
                R = scan_covariance(
                    res.information, int(res.inliers), float(res.mse), 0.02, CHAIN_BEAMS, weak
                )
                if mahalanobis2(guess, P, z, R) <= gate:
                    pose, P2 = fuse(guess, P, z, R)
                    cov = np.asarray(P2, dtype=np.float64)
                    t = float(np.clip(1.0 - math.sqrt(np.trace(P2) / np.trace(P)), 0.0, 1.0))
        out.append(pose)
        trust.append(t)
        covs.append(cov)
        spaced = kept is None or _apart(between(kept, pose), CHAIN_REF_STEP, CHAIN_REF_TURN)
        if pts.shape[0] >= 3 and spaced:
            kept = pose
            w, n = _chain_reference(pose, pts)
            world.append(w)
            normals.append(n)
            del world[:-keep], normals[:-keep]
        prev, prev_c = pose, c
    return out, trust, covs


def _exit_step_heading_sigma(u: Pose, motion: Any = None) -> float:
    """The heading sigma [rad] of a stretch's first chain step ``u`` (from the exit, the
    last verified pose, to the first scan outside): odometry alone (no earlier scan of the
    stretch to match), over the scans the exit detection took (simulated wing: 1.3-1.6 m
    of corridor). The localizer's motion model's (``motion``, a
    :class:`icploc.motion.MotionModel` with its learned noise gain; None: the configured
    alphas of :class:`icploc.config.LocalizerSection`): ``alpha1`` turn^2 + ``alpha2``
    travel^2 (0.36 deg/m), without its per-scan floor (this is one step) but with the
    chain's (:data:`CHAIN_ODOM_HEADING`); not the chain's 0.03 rad/m, which weighs a step
    against its scan match: over 1.4 m that is 2.6 deg, and the exit's heading no longer
    held the stretch (simulated wing, seed 18: the corridor's way in +0.5..0.7 deg off,
    the wing 7 cm off along it)."""
    from icploc.motion import MotionModel

    if motion is None:
        from icploc.config import LocalizerSection

        motion = MotionModel.from_config(LocalizerSection())
    motion = dataclasses.replace(motion, floor_xy=0.0, floor_theta=0.0)
    var = float(motion.motion_covariance(u)[2, 2])
    return math.sqrt(CHAIN_ODOM_HEADING[0] ** 2 + var)


def _chain_config() -> Any:
    """The ICP settings of the chain's scan-to-scans matches (no window search: the
    odometry's guess is close)."""
    from icploc._core import IcpConfig

    return IcpConfig(
        window_search=False,
        max_correspondence_distance=0.5,
        min_correspondence_distance=0.1,
    )


def _chain_reference(
    pose: Pose, pts: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A scan (robot frame ``pts``) drawn at ``pose`` as the chain's reference cloud: its
    points that have a normal, and those normals."""
    w = _to_world(pose, pts)
    n, ok = _scan_normals(w)
    return w[ok], n[ok]


def chain_heading_errors(
    scans: Sequence[NDArray[np.float64]],
    truth: NDArray[np.float64] | Sequence[Any],
    *,
    keep: int = 5,
    min_inliers: float = 0.6,
) -> NDArray[np.float64]:
    """How biased the chain's scan match is (a diagnostic against known poses): each scan
    (robot frame) matched as :func:`refined_poses` matches it, against its previous
    ``keep`` scans, but those drawn at their true poses ``truth`` and from its own true
    pose; per converged match explaining ``min_inliers`` of the scan, its heading minus
    the true one [rad]. The mean is the chain's heading bias per match."""
    from icploc._core import IcpError, MapIndex, icp

    t = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
    cfg = _chain_config()
    refs: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
    out: list[float] = []
    for i in range(keep, len(scans)):
        for j in range(i - keep, i):
            if j not in refs:
                refs[j] = _chain_reference((t[j, 0], t[j, 1], t[j, 2]), scans[j])
        refs.pop(i - keep - 1, None)
        w = np.concatenate([refs[j][0] for j in range(i - keep, i)])
        n = np.concatenate([refs[j][1] for j in range(i - keep, i)])
        if len(w) < 20 or len(scans[i]) < 20:
            continue
        try:
            res = icp(scans[i], MapIndex(w, n, None), (t[i, 0], t[i, 1], t[i, 2]), cfg)
        except IcpError:
            continue
        if res.converged and res.inlier_ratio >= min_inliers:
            out.append(wrap_angle(float(res.pose[2]) - float(t[i, 2])))
    return np.asarray(out, dtype=np.float64)


def _to_world(pose: Pose, pts: NDArray[np.float64]) -> NDArray[np.float64]:
    co, si = math.cos(pose[2]), math.sin(pose[2])
    return np.column_stack(
        [pose[0] + co * pts[:, 0] - si * pts[:, 1], pose[1] + si * pts[:, 0] + co * pts[:, 1]]
    )


def _relative_info(a: Pose, cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """The information of a world-frame pose covariance ``cov`` expressed in the frame of
    ``a`` (a relative constraint from node ``a``)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    rc = rot @ np.asarray(cov, dtype=np.float64) @ rot.T
    info = np.linalg.inv(rc + np.eye(3) * 1e-12)
    return 0.5 * (info + info.T)


@dataclass
class _Edge:
    i: int  #: from node (-1: the exit anchor)
    j: int
    z: Pose  #: the pose of j in the frame of i
    info: NDArray[np.float64]
    #: an odometry step: its translation is scaled by the stretch's odometry scale
    scaled: bool = False


@dataclass
class _Scale:
    """The stretch's odometry scale, a variable of the graph (prior 1 +- ``sigma``): the
    calibrated odometry's residual scale error along a corridor no scan constrains is
    what the loop matches elsewhere in the stretch (the room toured) measure."""

    sigma: float
    value: float = 1.0


def _linearized(
    x: NDArray[np.float64],
    edges: Sequence[_Edge],
    priors: Sequence[tuple[int, Pose, NDArray[np.float64]]],
    scale: _Scale | None,
) -> tuple[Any, NDArray[np.float64]]:
    """The whitened Jacobian (sparse, the poses' 3 N columns then the scale's) and
    residuals of the graph at ``x``."""
    from scipy.sparse import coo_matrix

    n = len(x)
    nv = 3 * n + (1 if scale is not None else 0)
    sv = scale.value if scale is not None else 1.0
    rows: list[NDArray[Any]] = []
    cols: list[NDArray[Any]] = []
    vals: list[NDArray[Any]] = []
    res = np.zeros(3 * (len(edges) + len(priors)) + (1 if scale is not None else 0))
    for k, e in enumerate(edges):
        L = np.linalg.cholesky(e.info + np.eye(3) * 1e-12).T
        xi, xj = x[e.i], x[e.j]
        c, s = math.cos(xi[2]), math.sin(xi[2])
        dx, dy = xj[0] - xi[0], xj[1] - xi[1]
        f = sv if (scale is not None and e.scaled) else 1.0
        r = np.array(
            [
                c * dx + s * dy - f * e.z[0],
                -s * dx + c * dy - f * e.z[1],
                wrap_angle(xj[2] - xi[2] - e.z[2]),
            ]
        )
        ji = np.array([[-c, -s, -s * dx + c * dy], [s, -c, -c * dx - s * dy], [0, 0, -1.0]])
        jj = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        res[3 * k : 3 * k + 3] = L @ r
        for node, jac in ((e.i, L @ ji), (e.j, L @ jj)):
            rr, cc = np.meshgrid(np.arange(3) + 3 * k, np.arange(3) + 3 * node, indexing="ij")
            rows.append(rr.ravel())
            cols.append(cc.ravel())
            vals.append(jac.ravel())
        if scale is not None and e.scaled:
            rows.append(np.arange(3) + 3 * k)
            cols.append(np.full(3, 3 * n))
            vals.append(L @ np.array([-e.z[0], -e.z[1], 0.0]))
    base = 3 * len(edges)
    for k, (node, p, w) in enumerate(priors):
        L = np.linalg.cholesky(w + np.eye(3) * 1e-12).T
        r = np.array([x[node, 0] - p[0], x[node, 1] - p[1], wrap_angle(x[node, 2] - p[2])])
        res[base + 3 * k : base + 3 * k + 3] = L @ r
        rr, cc = np.meshgrid(np.arange(3) + base + 3 * k, np.arange(3) + 3 * node, indexing="ij")
        rows.append(rr.ravel())
        cols.append(cc.ravel())
        vals.append(L.ravel())
    if scale is not None:
        last = len(res) - 1
        res[last] = (sv - 1.0) / scale.sigma
        rows.append(np.array([last]))
        cols.append(np.array([3 * n]))
        vals.append(np.array([1.0 / scale.sigma]))
    J = coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(len(res), nv),
    ).tocsc()
    return J, res


def _solve_graph(
    x0: NDArray[np.float64],
    edges: Sequence[_Edge],
    priors: Sequence[tuple[int, Pose, NDArray[np.float64]]],
    iterations: int = 15,
    scale: _Scale | None = None,
) -> NDArray[np.float64]:
    """Gauss-Newton on the SE(2) pose graph: ``edges`` (relative constraints),
    ``priors`` (absolute ones: node, pose, information); with ``scale`` the ``scaled``
    edges' translations are multiplied by a variable (updated in place). Returns the
    poses (N, 3)."""
    from scipy.sparse.linalg import spsolve

    x = np.array(x0, dtype=np.float64).reshape(-1, 3)
    n = len(x)
    for _ in range(iterations):
        J, res = _linearized(x, edges, priors, scale)
        H = (J.T @ J).tocsc()
        dx = spsolve(H, -(J.T @ res))
        x += dx[: 3 * n].reshape(-1, 3)
        x[:, 2] = np.angle(np.exp(1j * x[:, 2]))
        if scale is not None:
            scale.value += float(dx[3 * n])
        if float(np.abs(dx).max()) < 1e-6:
            break
    return x


def _marginals(
    x: NDArray[np.float64],
    edges: Sequence[_Edge],
    priors: Sequence[tuple[int, Pose, NDArray[np.float64]]],
    scale: _Scale | None,
    nodes: int = MARGINAL_NODES,
) -> NDArray[np.float64]:
    """Each node's marginal pose covariance (N, 3, 3) at the solution ``x``: the 3 x 3
    blocks of the inverse of the Gauss-Newton information (the scale a variable with
    the rest, so its uncertainty is in every pose's). Each block costs three back-solves
    against the whole factorization, so only about ``nodes`` of them are computed (every
    k-th node and the last; all when there are that few); a node between two computed
    ones gets their covariances interpolated linearly by node index: along a chain the
    covariance changes slowly from one scan to the next (centimetres apart) and, where
    odometry noise adds up, about linearly (exactly so for a position random walk).
    Between them it may bend (a chain held at both ends peaks mid-way), so the stand-in
    can be a little surer than the node's own (a 600-step chain held at both ends, every
    11th node computed: sigma at most 0.7 % surer, 1.3 % less sure than the node's own;
    tests/test_mappatch_sigma.py). Where loop edges pin nodes between two computed ones it
    bends more: a synthetic 5000-step chain with a loop edge every 10th node, every 25th
    node computed: position sigma within 11 % (p99 6 %), heading sigma up to 2.3 x off
    (p99 69 %, up to 49 % surer)."""
    from scipy.sparse import identity
    from scipy.sparse.linalg import splu

    J, _ = _linearized(x, edges, priors, scale)
    nv = J.shape[1]
    lu = splu(((J.T @ J) + identity(nv) * 1e-12).tocsc())
    n = len(x)
    step = max(1, math.ceil(n / max(1, int(nodes))))
    picked = np.unique(np.r_[np.arange(0, n, step), n - 1]) if n else np.zeros(0, np.int64)
    got = np.zeros((len(picked), 3, 3))
    chunk = 128  # nodes per solve: the inverse's columns a few at a time, never all
    for a in range(0, len(picked), chunk):
        sel = picked[a : a + chunk]
        rhs = np.zeros((nv, 3 * len(sel)))
        for m, k in enumerate(sel):
            rhs[3 * k : 3 * k + 3, 3 * m : 3 * m + 3] = np.eye(3)
        cols = lu.solve(rhs)
        for m, k in enumerate(sel):
            got[a + m] = cols[3 * k : 3 * k + 3, 3 * m : 3 * m + 3]
    # between two computed nodes the covariance interpolated linearly by node index (a
    # convex combination: still a covariance)
    k = np.arange(n)
    hi = np.clip(np.searchsorted(picked, k), 1, max(1, len(picked) - 1))
    lo = hi - 1
    if len(picked) < 2:
        return 0.5 * (got + got.transpose(0, 2, 1))[np.zeros(n, dtype=np.int64)]
    t = ((k - picked[lo]) / np.maximum(picked[hi] - picked[lo], 1))[:, None, None]
    out = (1.0 - t) * got[lo] + t * got[hi]
    return 0.5 * (out + out.transpose(0, 2, 1))


def graph_poses(*args: Any, **kwargs: Any) -> NDArray[np.float64]:
    """A stretch's poses from its pose graph (:func:`graph_solution`). Returns (N, 3)."""
    return graph_solution(*args, **kwargs)[0]


def graph_solution(
    start: Pose,
    scans: Sequence[NDArray[np.float64]],
    coasted: Sequence[Pose],
    lock: Pose | None,
    *,
    anchor_sigma: tuple[float, float] = (0.03, 0.01),
    keep: int = 5,
    keyframe_step: float = KEYFRAME_STEP,
    loop_radius: float = 5.0,
    loop_gap: float = 0.4,
    nearest: int = 12,
    rounds: int = 1,
    min_inliers: float = 0.6,
    outlier_chi2: float = 16.0,
    walls: MappedWalls | None = None,
    scale_sigma: float = 0.02,
    lead: tuple[Sequence[NDArray[np.float64]], Sequence[Pose]] | None = None,
    marginals: bool = False,
    sequence_reach: float | None = None,
    exit_motion: Any = None,
    lead_in: tuple[Sequence[NDArray[np.float64]], Sequence[Pose]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """A stretch's poses from a least-squares pose graph: node 0 is the exit (the last
    verified pose, held by a prior of ``anchor_sigma`` (m, rad)), then one node per scan;
    chain edges are the scan-matched odometry steps of :func:`refined_poses`; the
    re-entry ``lock`` (when there is one) is a second prior of ``anchor_sigma``. Solved
    once from the lock's correction spread along the chain (:func:`corrected_poses`),
    then loop edges are added: each keyframe scan (``keyframe_step`` m / :data:`KEYFRAME_TURN` apart, :func:`_apart`)
    matched against its ``nearest`` earlier keyframes within ``loop_radius`` (at least
    ``loop_gap`` m of travel and two scans back: the robot came by again, in the wing or
    on the way back), drawn at that solution; a loop edge the solved graph disagrees with
    (chi-square above ``outlier_chi2``) is dropped and the graph solved again. Heading is
    a variable like position, so a heading drift is undone where the scans constrain it.
    ``rounds`` > 1 re-matches at each new solution (measured in the simulated wing: it
    drifts away, 1 is best). ``lead``: scans after the lock and their poses by odometry
    from it (map frame): more nodes chained on from the lock, matched against the mapped
    walls with the rest (``walls``; the lock is one scan, they tie it to many), not
    returned. ``sequence_reach`` (default :data:`SEQUENCE_REACH`): each keyframe's heading
    also tied, pairwise, to the keyframes before it on its way within that reach
    (:func:`_sequence_edges`), so the chain's heading does not drift with the odometry's;
    0: none. ``exit_motion``: the localizer's motion model at the exit
    (:attr:`icploc.outside.Stretch.exit_motion`), the first step's heading noise
    (:func:`_exit_step_heading_sigma`). ``lead_in``: the scans between the exit and the
    first scan of the stretch and their poses in the dead reckoning's frame (the
    coasted poses' own: by odometry from the exit; :attr:`icploc.outside.Stretch.lead_in`):
    nodes chained in between, so the exit gap is scan-matched steps instead of one
    odometry step, and matched against the mapped walls with the rest; not returned.
    Returns the poses (N, 3) and, with ``marginals``, their marginal covariances (N, 3, 3;
    :func:`_marginals`) at the solution, else None."""
    from icploc._core import IcpConfig

    if len(coasted) == 0:
        return np.zeros((0, 3)), (np.zeros((0, 3, 3)) if marginals else None)
    # the lead-in's nodes first (1..m), then the stretch's (m+1..m+n), then the lead-out's
    m = 0
    if lead_in is not None and len(lead_in[0]):
        m = len(lead_in[0])
        coasted = [*((float(p[0]), float(p[1]), float(p[2])) for p in lead_in[1]), *coasted]
        scans = [*lead_in[0], *scans]
    n = len(coasted)  # the lead-in's and the stretch's nodes after the exit
    lead_poses: list[Pose] = []
    if lead is not None and lock is not None and len(lead[0]):
        l0 = (float(lock[0]), float(lock[1]), float(lock[2]))
        lead_poses = [(float(p[0]), float(p[1]), float(p[2])) for p in lead[1]]
        # in the dead reckoning's frame, on from its pose at the lock
        coasted = [*coasted, *(compose(coasted[-1], between(l0, p)) for p in lead_poses)]
        scans = [*scans, *lead[0]]
    total = len(coasted)
    chain, _, covs = _chain(
        start, scans, coasted, keep=keep, min_inliers=min_inliers, keyframe_step=keyframe_step,
        exit_motion=exit_motion,
    )  # fmt: skip
    s0 = (float(start[0]), float(start[1]), float(start[2]))
    nodes: list[Pose] = [s0, *chain]
    edges = [
        _Edge(
            k, k + 1, between(nodes[k], nodes[k + 1]), _relative_info(nodes[k], covs[k]), True
        )
        for k in range(total)
    ]
    sc = _Scale(scale_sigma) if (scale_sigma > 0 and lock is not None) else None
    sx, sth = anchor_sigma
    w_anchor = np.diag([1 / sx**2, 1 / sx**2, 1 / sth**2])
    priors: list[tuple[int, Pose, NDArray[np.float64]]] = [(0, s0, w_anchor)]
    if lock is not None:
        priors.append((n, (float(lock[0]), float(lock[1]), float(lock[2])), w_anchor))
    if sequence_reach is None:
        sequence_reach = SEQUENCE_REACH
    if sequence_reach > 0.0:
        # the chain's long baselines: each keyframe matched against the keyframes before
        # it on its way (pairwise, in their own frames: no pose of the chain in the match)
        xc = np.asarray(nodes, dtype=np.float64)
        chain_var = np.concatenate([[0.0], np.cumsum([float(c[2, 2]) for c in covs])])
        seq = _sequence_edges(
            xc, _keyframes(xc, scans, keyframe_step), scans, sequence_reach, min_inliers,
            chain_var, outlier_chi2, keep,
        )  # fmt: skip
    else:
        seq = []
    x = np.asarray(nodes, dtype=np.float64)
    if lock is not None:
        x[1 : n + 1] = corrected_poses(s0, chain[:n], chain[n - 1], lock)
        if lead_poses:
            x[n + 1 :] = lead_poses
        x = _solve_graph(x, [*edges, *seq], priors, scale=sc)
        # a heading match the rest of the graph disagrees with is dropped, as a loop's
        keep_seq = [e for e in seq if _chi2(x, e) <= outlier_chi2]
        if len(keep_seq) < len(seq):
            x = _solve_graph(x, [*edges, *keep_seq], priors, scale=sc)
        seq = keep_seq
    edges = [*edges, *seq]
    # loop edges: keyframes against earlier keyframes nearby
    cfg = IcpConfig(
        window_search=False, max_correspondence_distance=0.3, min_correspondence_distance=0.05
    )
    keys = _keyframes(x, scans, keyframe_step)
    for _ in range(rounds):
        loop = _loop_edges(x, keys, scans, cfg, loop_radius, loop_gap, nearest, min_inliers)
        if not loop:
            break
        y = _solve_graph(x, [*edges, *loop], priors, scale=sc)
        # a loop match the rest of the graph disagrees with (an aliased corridor, a
        # wrong wall) is dropped and the graph solved without it
        keep_loop = [e for e in loop if _chi2(y, e) <= outlier_chi2]
        if len(keep_loop) < len(loop):
            x = _solve_graph(y, [*edges, *keep_loop], priors, scale=sc)
        else:
            x = y
        edges = [*edges, *keep_loop]
    if walls is not None:
        mp = walls.priors(x, scans)
        if mp:
            x, keep_p = _wall_prior_solve(x, edges, priors, mp, sc, outlier_chi2)
            priors = [*priors, *keep_p]
    cov = _marginals(x, edges, priors, sc)[m + 1 : n + 1] if marginals else None
    return x[m + 1 : n + 1], cov


def _keyframes(x: NDArray[np.float64], scans: Sequence[NDArray[np.float64]], step: float) -> list[int]:
    """The graph's keyframe nodes (node k is scan k - 1): the first scan with 20 points,
    then each scan that far from the last keyframe (:func:`_apart`) at the poses ``x``."""
    keys: list[int] = []
    for k in range(1, len(x)):
        if scans[k - 1].shape[0] < 20:
            continue
        if not keys or _apart(between(tuple(x[keys[-1]]), tuple(x[k])), step):
            keys.append(k)
    return keys


def _sequence_edges(
    x: NDArray[np.float64],
    keys: Sequence[int],
    scans: Sequence[NDArray[np.float64]],
    reach: float,
    min_inliers: float,
    chain_var: NDArray[np.float64],
    gate: float,
    skip: int = 0,
) -> list[_Edge]:
    """Heading edges from matching each keyframe's scan against each earlier keyframe's
    scan on its way within ``reach`` (metres travelled plus 0.3 per radian turned, at the
    poses ``x``; :data:`SEQUENCE_REACH`), pairwise: the reference drawn in its own frame,
    the guess the chain's relative pose. The edge constrains the relative heading only, by
    the match's marginal heading variance (:func:`icploc.fusion.scan_covariance`, the
    chain's :data:`CHAIN_BEAMS`, a direction held by fewer than :data:`WEAK_AXIS_BEAMS`
    beams left free). Translation stays the chain's: pairwise translations make the toured
    part rigid and hang it on a corridor's length, which no scan there measures (simulated
    wing, seed 13, the full edges: the wing 7-10 cm off along the corridor, 91.5 % of its
    walls within 10 cm; the heading only: 100 %). A match whose heading disagrees with the
    chain's beyond the chi-square ``gate`` (the chain's heading variance between the two,
    ``chain_var[k] - chain_var[j]``, plus the match's) is no edge; nor is a pair at most
    ``skip`` scans apart: the chain matched those already (its ``keep`` previous scans), and
    counted twice the same match would outweigh the rest of the graph. So on the real logs'
    steps (0.5 m, every scan a keyframe, the previous five reach 2.5 m back) there is no
    such edge: measured with them, aces 90 -> 85 %, freiburg-079 93 -> 88 % of the patch's
    walls within 10 cm."""
    from icploc._core import IcpConfig, IcpError, MapIndex, icp
    from icploc.fusion import scan_covariance

    cfg = IcpConfig(
        window_search=False, max_correspondence_distance=0.3, min_correspondence_distance=0.05
    )
    steps = np.hypot(np.diff(x[:, 0]), np.diff(x[:, 1])) + 0.3 * np.abs(
        np.angle(np.exp(1j * np.diff(x[:, 2])))
    )
    travel = np.concatenate([[0.0], np.cumsum(steps)])
    local: dict[int, Any] = {}
    out: list[_Edge] = []
    for a, k in enumerate(keys):
        for j in keys[:a][::-1]:
            if travel[k] - travel[j] > reach:
                break
            if k - j <= skip:
                continue  # the chain matched scan k against scan j already
            if j not in local:
                w, nrm = _chain_reference((0.0, 0.0, 0.0), scans[j - 1])
                local[j] = MapIndex(w, nrm, None) if len(w) >= 20 else None
            if local[j] is None:
                continue
            guess = between(tuple(x[j]), tuple(x[k]))
            try:
                r = icp(scans[k - 1], local[j], guess, cfg)
            except IcpError:
                continue
            if not (r.converged and r.inlier_ratio >= min_inliers):
                continue
            z = (float(r.pose[0]), float(r.pose[1]), float(r.pose[2]))
            if (
                math.hypot(z[0] - guess[0], z[1] - guess[1]) > 0.5
                or abs(wrap_angle(z[2] - guess[2])) > 0.15
            ):
                continue
            R = scan_covariance(
                r.information, int(r.inliers), float(r.mse), 0.02, CHAIN_BEAMS, WEAK_AXIS_BEAMS
            )
            var = float(R[2, 2])
            d = wrap_angle(z[2] - guess[2])
            if d * d > gate * (float(chain_var[k] - chain_var[j]) + var):
                continue
            # the heading only: the match's marginal heading variance
            out.append(_Edge(j, k, z, np.diag([0.0, 0.0, 1.0 / var])))
    return out


def _wall_prior_solve(
    x: NDArray[np.float64],
    edges: Sequence[_Edge],
    priors: Sequence[tuple[int, Pose, NDArray[np.float64]]],
    mp: Sequence[tuple[int, Pose, NDArray[np.float64]]],
    scale: _Scale | None,
    gate: float,
    per_dof: float | None = None,
) -> tuple[NDArray[np.float64], list[tuple[int, Pose, NDArray[np.float64]]]]:
    """The graph solved from ``x`` with the mapped walls' priors ``mp`` (:class:`MappedWalls`)
    added to ``priors``: a wall prior the solved graph disagrees with beyond the
    chi-square ``gate`` is dropped and the graph solved again; then each kept wall prior's
    information is scaled by ``min(1, per_dof * dof / chi2)`` (``chi2`` its residual at
    that solution, ``dof`` the prior's degrees of freedom, :func:`_prior_dof`; default
    :data:`WALL_PRIOR_CHI2_PER_DOF`; 0 or less: no scaling) and the graph solved once
    more. Returns the poses and the wall priors as used."""
    if per_dof is None:
        per_dof = WALL_PRIOR_CHI2_PER_DOF
    y = _solve_graph(x, edges, [*priors, *mp], scale=scale)
    keep = [q for q in mp if _prior_chi2(y, q) <= gate]
    if len(keep) < len(mp):
        y = _solve_graph(y, edges, [*priors, *keep], scale=scale)
    if per_dof > 0.0 and keep:
        f = []
        for q in keep:
            dof = _prior_dof(q[2])
            c = _prior_chi2(y, q)
            f.append(min(1.0, per_dof * dof / c) if dof > 0 and c > 0.0 else 1.0)
        if min(f) < 1.0:
            keep = [(k, z, w * s) for (k, z, w), s in zip(keep, f, strict=True)]
            y = _solve_graph(y, edges, [*priors, *keep], scale=scale)
    return y, keep


def _prior_dof(w: NDArray[np.float64], tol: float = WALL_PRIOR_RANK_TOL) -> int:
    """A prior's degrees of freedom: the numerical rank of its information ``w`` (3 x 3),
    the eigenvalues above ``tol`` times the largest (:data:`WALL_PRIOR_RANK_TOL`)."""
    ev = np.linalg.eigvalsh(0.5 * (w + w.T))
    if not ev[-1] > 0.0:
        return 0
    return int(np.sum(ev > tol * ev[-1]))


def _prior_chi2(x: NDArray[np.float64], q: tuple[int, Pose, NDArray[np.float64]]) -> float:
    k, p, w = q
    r = np.array([x[k, 0] - p[0], x[k, 1] - p[1], wrap_angle(x[k, 2] - p[2])])
    return float(r @ w @ r)


@dataclass
class MappedWalls:
    """The map a stretch left and came back to: its index (walls) and where it knows
    anything (:class:`icploc.outside.MappedArea`). A stretch's scan whose beams partly end
    on mapped walls (the hall seen through the door behind, the mapped walls near the
    exit and the re-entry) is matched against them: a prior on its pose in the
    directions those walls constrain."""

    index: Any
    area: Any
    min_points: int = 30
    min_inliers: float = 0.8
    max_shift: float = 0.3
    min_axis_beams: float = 8.0

    def priors(
        self, x: NDArray[np.float64], scans: Sequence[NDArray[np.float64]]
    ) -> list[tuple[int, Pose, NDArray[np.float64]]]:
        from icploc._core import IcpConfig, IcpError, icp
        from icploc.fusion import scan_covariance

        cfg = IcpConfig(
            window_search=False, max_correspondence_distance=0.3, min_correspondence_distance=0.05
        )
        out: list[tuple[int, Pose, NDArray[np.float64]]] = []
        for k in range(1, len(x)):
            pts = scans[k - 1]
            guess = (float(x[k, 0]), float(x[k, 1]), float(x[k, 2]))
            w = _to_world(guess, pts)
            on = ~self.area.unmapped(w)
            if int(on.sum()) < self.min_points:
                continue
            d, _ = self.index.nearest(np.ascontiguousarray(w[on]))
            sub = np.ascontiguousarray(pts[on][np.asarray(d) < 0.3])
            if len(sub) < self.min_points:
                continue
            try:
                r = icp(sub, self.index, guess, cfg)
            except IcpError:
                continue
            if not (r.converged and r.inlier_ratio >= self.min_inliers):
                continue
            z = (float(r.pose[0]), float(r.pose[1]), float(r.pose[2]))
            if math.hypot(z[0] - guess[0], z[1] - guess[1]) > self.max_shift:
                continue
            R = scan_covariance(
                r.information, int(r.inliers), float(r.mse), 0.02, 5.0, self.min_axis_beams
            )
            info = np.linalg.inv(np.asarray(R, dtype=np.float64) + np.eye(3) * 1e-12)
            out.append((k, z, 0.5 * (info + info.T)))
        return out


def _chi2(x: NDArray[np.float64], e: _Edge) -> float:
    """The squared Mahalanobis residual of edge ``e`` at the poses ``x``."""
    d = between((x[e.i, 0], x[e.i, 1], x[e.i, 2]), (x[e.j, 0], x[e.j, 1], x[e.j, 2]))
    r = np.array([d[0] - e.z[0], d[1] - e.z[1], wrap_angle(d[2] - e.z[2])])
    return float(r @ e.info @ r)


def _loop_edges(
    x: NDArray[np.float64],
    keys: Sequence[int],
    scans: Sequence[NDArray[np.float64]],
    cfg: Any,
    radius: float,
    gap: float,
    nearest: int,
    min_inliers: float,
) -> list[_Edge]:
    """Edges from matching each keyframe's scan against its ``nearest`` earlier keyframes
    (at least ``gap`` m of travel and two scans back, within ``radius``) drawn at the
    poses ``x``."""

    local: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
    for k in keys:
        w = _to_world((x[k, 0], x[k, 1], x[k, 2]), scans[k - 1])
        nrm, ok = _scan_normals(w)
        local[k] = (w[ok], nrm[ok])
    ks = np.asarray(keys)
    steps = np.hypot(np.diff(x[:, 0]), np.diff(x[:, 1]))
    travel = np.concatenate([[0.0], np.cumsum(steps)])
    out: list[_Edge] = []
    for k in keys:
        cand = ks[(ks < k - 1) & (travel[ks] <= travel[k] - gap)]
        if len(cand) < 2:
            continue
        dist = np.hypot(x[cand, 0] - x[k, 0], x[cand, 1] - x[k, 1])
        order = np.argsort(dist)[:nearest]
        near = [int(cand[i]) for i in order if dist[i] <= radius]
        if len(near) < 2:
            continue
        e = _match_edge(x, k, near, local, scans[k - 1], cfg, min_inliers)
        if e is not None:
            out.append(e)
    return out


def _match_edge(
    x: NDArray[np.float64],
    k: int,
    group: Sequence[int],
    local: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]],
    pts: NDArray[np.float64],
    cfg: Any,
    min_inliers: float,
) -> _Edge | None:
    """Scan ``k`` matched against the keyframes ``group`` drawn at ``x``: an edge from
    the group's first keyframe, or None when the match fails its checks."""
    from icploc._core import IcpError, MapIndex, icp
    from icploc.fusion import scan_covariance

    ref = np.concatenate([local[j][0] for j in group])
    nrm = np.concatenate([local[j][1] for j in group])
    if len(ref) < 20:
        return None
    guess = (float(x[k, 0]), float(x[k, 1]), float(x[k, 2]))
    try:
        r = icp(pts, MapIndex(ref, nrm, None), guess, cfg)
    except IcpError:
        return None
    if not (r.converged and r.inlier_ratio >= min_inliers):
        return None
    z = (float(r.pose[0]), float(r.pose[1]), float(r.pose[2]))
    if (
        math.hypot(z[0] - guess[0], z[1] - guess[1]) > 0.5
        or abs(wrap_angle(z[2] - guess[2])) > 0.15
    ):
        return None
    R = scan_covariance(r.information, int(r.inliers), float(r.mse), 0.02, 5.0, WEAK_AXIS_BEAMS)
    a = group[0]
    pa = (float(x[a, 0]), float(x[a, 1]), float(x[a, 2]))
    return _Edge(a, k, between(pa, z), _relative_info(pa, R))


def _scan_normals(w: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Unit normals of a scan's points (beam order) from their neighbours, and which points
    have a usable one (neighbours close and on a line through the point)."""
    d = w[2:] - w[:-2]
    ln = np.hypot(d[:, 0], d[:, 1])
    n = np.zeros_like(w)
    ok = np.zeros(len(w), dtype=bool)
    good = (ln > 1e-6) & (ln < 0.5)
    n[1:-1][good] = np.column_stack([-d[good, 1], d[good, 0]]) / ln[good, None]
    ok[1:-1] = good
    return n, ok



#: a stretch's scan-to-submap match (:func:`submap_poses`) is verified when it converged,
#: explains at least this share of the scan and moved the odometry's guess by at most
#: :data:`SUBMAP_MAX_SHIFT` m / :data:`SUBMAP_MAX_TURN` rad
SUBMAP_MIN_INLIERS = 0.6
#: (see :data:`SUBMAP_MIN_INLIERS`) [m]
SUBMAP_MAX_SHIFT = 0.5
#: (see :data:`SUBMAP_MIN_INLIERS`) [rad]
SUBMAP_MAX_TURN = 0.15
#: the submap's points are those of the scans placed so far within this distance of the
#: scan's guessed position [m] (the laser's reach on the real logs: 30 m)
SUBMAP_RADIUS = 30.0
#: a stretch's submap placement needs at least this share of its scans' matches verified
#: (:data:`SUBMAP_MIN_INLIERS`), else the pose graph's placement stands
SUBMAP_MIN_VERIFIED = 0.5
#: :func:`self_consistency`: a beam end agrees with another scan's within this [m] (10 cm
#: told the placements of tests/test_part_submap.py's drive apart the wrong way round:
#: 0.959 / 0.965, its walls 95.8 / 62.3 % within 10 cm)
SUBMAP_CONSISTENCY_NEAR = 0.05
#: :func:`self_consistency`: ... of a keyframe more than this far away along the way [m
#: travelled] (a scan's neighbours overlap it whatever the placement)
SUBMAP_CONSISTENCY_APART = 3.0
#: the submap placement replaces the pose graph's only when its :func:`self_consistency`
#: is higher by more than this: the simulated wing's two placements (scans 4 cm apart;
#: the graph's walls 99.9 / 100 % within 10 cm, the submap's 90.2 / 91.0 %, seeds 3 / 24)
#: score 0.962 / 0.964 and 0.960 / 0.968 (submap / graph); the real logs' stretches where
#: the submap's walls are better 0.02-0.32 higher (aces, belgioioso, csail, freiburg-079,
#: freiburg-101, intel); tests/test_part_submap.py's drive 0.910 / 0.899
SUBMAP_CONSISTENCY_GAIN = 0.01
#: :func:`self_consistency`'s keyframes are this far apart [m travelled] (the real logs'
#: scans are 0.5 m apart: all of theirs)
SUBMAP_CONSISTENCY_SPACING = 0.5


@dataclass
class SubmapRefinement:
    """What :func:`submap_poses` made of a stretch: its poses, per scan whether its match
    verified, and the loop error left at the lock (metres, radians) before it was spread,
    against the dead reckoning's (the lock's correction)."""

    poses: NDArray[np.float64]
    verified: NDArray[np.bool_]
    loop_error_m: float
    loop_error_rad: float
    odometry_error_m: float

    @property
    def verified_share(self) -> float:
        return float(np.mean(self.verified)) if len(self.verified) else 0.0

    def record(self) -> dict[str, Any]:
        """The figures a patch's YAML lists of it (rounded)."""
        return {
            "submap_matches_verified": int(self.verified.sum()),
            "submap_scans": len(self.verified),
            "submap_loop_error_m": round(self.loop_error_m, 3),
            "submap_loop_error_deg": round(math.degrees(self.loop_error_rad), 2),
            "odometry_loop_error_m": round(self.odometry_error_m, 3),
        }


def self_consistency(
    scans: Sequence[NDArray[np.float64]],
    poses: NDArray[np.float64] | Sequence[Any],
    travel: NDArray[np.float64] | Sequence[float],
    near: float = SUBMAP_CONSISTENCY_NEAR,
    apart: float = SUBMAP_CONSISTENCY_APART,
    spacing: float = SUBMAP_CONSISTENCY_SPACING,
) -> float:
    """How well a placement of a stretch's scans (robot frame, at ``poses``) agrees with
    itself, without any truth: of the keyframe scans (``spacing`` m of ``travel`` apart,
    the metres travelled to each scan: the same scans whatever the placement, and as many
    per metre whether the scans are centimetres or half a metre apart), the share of the
    beam ends within ``near`` m of a beam end of a keyframe more than ``apart`` m of travel
    away (another look at the same wall, not the scan's neighbour). 0 without such points."""
    from scipy.spatial import cKDTree

    tr = np.asarray(travel, dtype=np.float64)
    keys: list[int] = []
    for k in range(len(scans)):
        if np.asarray(scans[k]).size and (not keys or tr[k] - tr[keys[-1]] >= spacing):
            keys.append(k)
    if len(keys) < 2:
        return 0.0
    w = [
        _to_world(
            (float(poses[k][0]), float(poses[k][1]), float(poses[k][2])),
            np.asarray(scans[k], dtype=np.float64).reshape(-1, 2),
        )
        for k in keys
    ]
    at = np.concatenate([np.full(len(a), tr[k]) for a, k in zip(w, keys, strict=True)])
    pts = np.concatenate(w)
    hit = 0
    for a, k in zip(w, keys, strict=True):
        far = np.abs(at - tr[k]) > apart
        if not far.any():
            continue
        d, _ = cKDTree(pts[far]).query(a, k=1, distance_upper_bound=near)
        hit += int(np.sum(np.isfinite(d)))
    return hit / len(pts)


def _travel(start: Pose, poses: Sequence[Pose]) -> NDArray[np.float64]:
    """Metres travelled from ``start`` to each of ``poses``."""
    p = np.asarray([start, *poses], dtype=np.float64).reshape(-1, 3)
    return np.cumsum(np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1])))


def submap_poses(
    start: Pose,
    scans: Sequence[NDArray[np.float64]],
    coasted: Sequence[Pose],
    lock: Pose,
    *,
    lead_in: tuple[Sequence[NDArray[np.float64]], Sequence[Pose]] | None = None,
    min_inliers: float = SUBMAP_MIN_INLIERS,
    radius: float = SUBMAP_RADIUS,
) -> SubmapRefinement:
    """A stretch's poses by sequential scan-to-submap ICP (the core's :func:`icploc._core.icp`):
    each scan, from the odometry step on from the pose found for the previous one, matched
    against a point index of the stretch's scans placed so far (the lead-in's first, from
    the exit pose: the submap starts at the exit anchor); a match that does not verify
    (:data:`SUBMAP_MIN_INLIERS`, :data:`SUBMAP_MAX_SHIFT`, :data:`SUBMAP_MAX_TURN`) leaves
    the odometry step. The loop error left at the lock (the last scan's pose against
    ``lock``) is spread along the stretch (:func:`corrected_poses`, a verified step
    taking a tenth of an odometry step's share). ``coasted``: the dead reckoning's poses,
    the last one what it said at the lock. Returns the poses of ``scans`` (not the
    lead-in's) and how the matches went."""
    from icploc._core import IcpError, MapIndex, icp

    cfg = _chain_config()
    s0: Pose = (float(start[0]), float(start[1]), float(start[2]))
    m = 0
    all_scans = list(scans)
    all_coasted = [(float(p[0]), float(p[1]), float(p[2])) for p in coasted]
    if lead_in is not None and len(lead_in[0]):
        m = len(lead_in[0])
        all_scans = [*lead_in[0], *all_scans]
        all_coasted = [*((float(p[0]), float(p[1]), float(p[2])) for p in lead_in[1]), *all_coasted]
    pts_w: list[NDArray[np.float64]] = []
    nrm_w: list[NDArray[np.float64]] = []
    out: list[Pose] = []
    ok: list[bool] = []
    prev, prev_c = s0, s0
    for pts, c in zip(all_scans, all_coasted, strict=True):
        guess = compose(prev, between(prev_c, c))
        pose, good = guess, False
        if pts_w and pts.shape[0] >= 20:
            w = np.concatenate(pts_w)
            n = np.concatenate(nrm_w)
            near = np.hypot(w[:, 0] - guess[0], w[:, 1] - guess[1]) <= radius
            if int(near.sum()) >= 20:
                try:
                    r = icp(pts, MapIndex(w[near], n[near], None), guess, cfg)
                except IcpError:
                    r = None
                if r is not None and r.converged and r.inlier_ratio >= min_inliers:
                    z = (float(r.pose[0]), float(r.pose[1]), float(r.pose[2]))
                    if (
                        math.hypot(z[0] - guess[0], z[1] - guess[1]) <= SUBMAP_MAX_SHIFT
                        and abs(wrap_angle(z[2] - guess[2])) <= SUBMAP_MAX_TURN
                    ):
                        pose, good = z, True
        out.append(pose)
        ok.append(good)
        if pts.shape[0] >= 3:
            w1, n1 = _chain_reference(pose, pts)
            pts_w.append(w1)
            nrm_w.append(n1)
        prev, prev_c = pose, c
    end = out[-1]
    lk = (float(lock[0]), float(lock[1]), float(lock[2]))
    trust = [1.0 if g else 0.0 for g in ok]
    x = corrected_poses(s0, out, end, lk, trust=trust)
    dr = all_coasted[-1]
    return SubmapRefinement(
        poses=x[m:],
        verified=np.asarray(ok[m:], dtype=bool),
        loop_error_m=math.hypot(lk[0] - end[0], lk[1] - end[1]),
        loop_error_rad=abs(wrap_angle(lk[2] - end[2])),
        odometry_error_m=math.hypot(lk[0] - dr[0], lk[1] - dr[1]),
    )


def _submap_or_graph(
    st: Stretch,
    scans: Sequence[NDArray[np.float64]],
    coasted: Sequence[Pose],
    graph: NDArray[np.float64],
    lead_in: tuple[Sequence[NDArray[np.float64]], Sequence[Pose]],
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """A stretch back in the map placed by its own scans matched to each other
    (:func:`submap_poses`) when that verifies: at least :data:`SUBMAP_MIN_VERIFIED` of
    its matches verified and the placement agrees with itself clearly better than the
    pose graph's (:func:`self_consistency`, by more than :data:`SUBMAP_CONSISTENCY_GAIN`);
    else the pose graph's placement ``graph`` stands. Returns the poses and what chose them (:attr:`icploc.outside.Stretch.patch_placement`)."""
    assert st.lock_pose is not None
    r = submap_poses(st.exit_pose, scans, coasted, st.lock_pose, lead_in=lead_in)
    travel = _travel(st.exit_pose, coasted)
    c_sub = self_consistency(scans, r.poses, travel)
    c_graph = self_consistency(scans, graph, travel)
    rec: dict[str, Any] = {
        **r.record(),
        "submap_self_consistency": round(c_sub, 3),
        "graph_self_consistency": round(c_graph, 3),
    }
    if r.verified_share >= SUBMAP_MIN_VERIFIED and c_sub > c_graph + SUBMAP_CONSISTENCY_GAIN:
        return r.poses, {"placement": "submap", **rec}
    why = (
        f"{rec['submap_matches_verified']} of {rec['submap_scans']} submap matches verified"
        if r.verified_share < SUBMAP_MIN_VERIFIED
        else "the submap placement agrees with itself no better than the pose graph's"
    )
    return graph, {"placement": "graph", "why": why, **rec}


def _stretch_poses(
    st: Stretch, refine: bool = True, walls: MappedWalls | None = None
) -> NDArray[np.float64]:
    return _stretch_solution(st, refine, walls)[0]


def _stretch_solution(
    st: Stretch, refine: bool = True, walls: MappedWalls | None = None, marginals: bool = False
) -> tuple[NDArray[np.float64], list[NDArray[np.float64] | None]]:
    """A stretch's poses and, with ``marginals``, per scan its pose covariance: the pose
    graph's marginal for a stretch back in the map, None for poses nothing checked at
    their far end (a stretch not back, or not refined)."""
    coasted: list[Pose] = [p for _, _, p in st.scans]
    none: list[NDArray[np.float64] | None] = [None] * len(coasted)
    if not coasted:
        return np.zeros((0, 3)), []
    closed = st.lock_pose is not None and st.correction is not None
    if closed and st.lock_pose is not None and st.correction is not None:
        c, lock = st.correction, st.lock_pose
        # what dead reckoning said at the lock
        coasted[-1] = (lock[0] - c[0], lock[1] - c[1], wrap_angle(lock[2] - c[2]))
    scans = [pts for _, pts, _ in st.scans]
    if refine and closed and st.lock_pose is not None:
        lead = ([q for _, q, _ in st.lead_out], [p for _, _, p in st.lead_out])
        lead_in = ([q for _, q, _ in st.lead_in], [p for _, _, p in st.lead_in])
        x, cov = graph_solution(
            st.exit_pose, scans, coasted, st.lock_pose, walls=walls, lead=lead,
            marginals=marginals, exit_motion=st.exit_motion, lead_in=lead_in,
        )  # fmt: skip
        y, st.patch_placement = _submap_or_graph(st, scans, coasted, x, lead_in)
        if cov is not None and st.patch_placement["placement"] == "submap":
            # the graph's marginals, no surer than the two placements agree: each scan's
            # covariance widened by the square of the difference of its poses
            d = y - x
            d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
            cov = cov + np.einsum("ni,ij->nij", d * d, np.eye(3))
        return y, (none if cov is None else list(cov))
    if refine:
        # not back yet: no second anchor; the loop edges alone measured worse (belgioioso
        # 31 % -> 26 % of the patch's walls within 10 cm) than the re-chained odometry
        coasted, _ = refined_poses(st.exit_pose, scans, coasted)
    if not closed or st.lock_pose is None:
        return np.asarray(coasted, dtype=np.float64).reshape(-1, 3), none
    return corrected_poses(st.exit_pose, coasted, coasted[-1], st.lock_pose), none


def wall_sigmas(
    pts: NDArray[np.float64], pose: Pose, cov: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Per beam end of a scan (robot frame ``pts``) drawn at ``pose`` with the pose
    covariance ``cov`` (3 x 3, map frame), the sigma [m] of where it puts the wall, along
    the wall's normal (from the beam ends beside it; along the beam where they do not
    make one): ``n' A cov A' n`` with ``A`` the end's derivative by the pose."""
    w = _to_world(pose, pts)
    n, ok = _scan_normals(w)
    rel = w - np.array([pose[0], pose[1]])
    beam = rel / np.maximum(np.hypot(rel[:, 0], rel[:, 1]), 1e-9)[:, None]
    n = np.where(ok[:, None], n, beam)
    # d end / d (x, y, theta) projected on n: (n_x, n_y, n . (-rel_y, rel_x))
    a = np.column_stack([n[:, 0], n[:, 1], -n[:, 0] * rel[:, 1] + n[:, 1] * rel[:, 0]])
    var = np.einsum("ij,jk,ik->i", a, np.asarray(cov, dtype=np.float64), a)
    return np.sqrt(np.maximum(var, 0.0))


def cell_sigmas(
    grid: BuiltGrid,
    scans: Sequence[NDArray[np.float64]],
    poses: NDArray[np.float64] | Sequence[Any],
    covs: Sequence[NDArray[np.float64] | None],
) -> NDArray[np.float64]:
    """Per cell of ``grid`` (drawn from ``scans`` at ``poses``) how surely its walls lie
    where they are drawn: the root mean square of :func:`wall_sigmas` over the beam ends
    in the cell whose pose has a covariance [m]; a beam end whose pose has none
    (``covs[i]`` None: dead reckoning nothing checked) is left out, so a cell is inf only
    when none of its beam ends has one; NaN in a cell no beam ends in. A scan at a
    non-finite pose is skipped (as :func:`grid_from_scans` does)."""
    res = float(grid.resolution)
    ox, oy = float(grid.origin[0]), float(grid.origin[1])
    rows, cols = grid.occupied.shape
    s2 = np.zeros(rows * cols)
    cnt = np.zeros(rows * cols)  # beam ends with a sigma
    ends = np.zeros(rows * cols)  # all beam ends
    for pts, pose, cov in zip(scans, poses, covs, strict=True):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0] == 0 or not np.isfinite(np.asarray(pose, dtype=np.float64)).all():
            continue
        p = (float(pose[0]), float(pose[1]), float(pose[2]))
        w = _to_world(p, pts)
        ok = np.isfinite(w).all(axis=1)
        ij = np.zeros((len(w), 2), dtype=np.int64)
        ij[ok] = np.floor((w[ok] - (ox, oy)) / res).astype(np.int64)
        inside = ok & (ij[:, 0] >= 0) & (ij[:, 0] < cols) & (ij[:, 1] >= 0) & (ij[:, 1] < rows)
        flat = ij[inside, 1] * cols + ij[inside, 0]
        ends += np.bincount(flat, minlength=rows * cols)
        if cov is None:
            continue
        sig = wall_sigmas(pts, p, cov)[inside]
        fin = np.isfinite(sig)
        s2 += np.bincount(flat[fin], sig[fin] ** 2, minlength=rows * cols)
        cnt += np.bincount(flat[fin], minlength=rows * cols)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.sqrt(s2 / cnt)
    out[(cnt == 0) & (ends > 0)] = np.inf
    out[ends == 0] = np.nan
    return out.reshape(rows, cols)


def grid_from_scans(
    scans: Sequence[NDArray[np.float64]],
    poses: NDArray[np.float64] | Sequence[Any],
    *,
    resolution: float = PATCH_RESOLUTION,
    align: tuple[float, float] = (0.0, 0.0),
    mounting: Pose = (0.0, 0.0, 0.0),
    margin: float = 0.5,
    min_hits: int | None = None,
    peak_share: float = 0.0,
) -> BuiltGrid | None:
    """Ray-cast robot-frame scan points (each an (N, 2) array of beam ends) at robot
    ``poses`` into one grid whose cell corners lie on ``align`` + multiples of
    ``resolution``; the beams start at ``mounting``. The occupancy rules are
    :func:`icploc.maps.build.build_grid`'s; ``peak_share`` > 0 then drops an occupied
    cell with fewer hits than that share of the most hit cell within
    :data:`PATCH_PEAK_RADIUS` of it (a wall's fringe: :data:`PATCH_PEAK_SHARE`). None
    without a point."""
    from icploc.maps.build import BUILD_DEFAULTS, grid_from_rays

    res = float(resolution)
    if not (math.isfinite(res) and res > 0):
        raise ValueError(f"map patch: resolution must be a positive number, got {resolution!r}")
    origins: list[NDArray[np.float64]] = []
    ends: list[NDArray[np.float64]] = []
    used = 0
    for pts, pose in zip(scans, poses, strict=True):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0] == 0 or not np.isfinite(np.asarray(pose, dtype=np.float64)).all():
            continue
        p = (float(pose[0]), float(pose[1]), float(pose[2]))
        c, s = math.cos(p[2]), math.sin(p[2])
        ends.append(
            np.column_stack(
                [p[0] + c * pts[:, 0] - s * pts[:, 1], p[1] + s * pts[:, 0] + c * pts[:, 1]]
            )
        )
        origins.append(np.broadcast_to(np.array(compose(p, mounting)[:2]), pts.shape))
        used += 1
    if not used:
        return None
    e = np.ascontiguousarray(np.concatenate(ends))
    o = np.ascontiguousarray(np.concatenate(origins))
    lo = np.minimum(e.min(axis=0), o.min(axis=0)) - margin
    hi = np.maximum(e.max(axis=0), o.max(axis=0)) + margin
    need = BUILD_DEFAULTS["min_hits"] if min_hits is None else int(min_hits)
    try:
        g = grid_from_rays(
            o, e, np.ones(len(e), dtype=bool), lo, hi, res, align=align, min_hits=need,
            occupied_ratio=BUILD_DEFAULTS["occupied_ratio"], scans_used=used,
        )  # fmt: skip
    except ValueError as exc:
        raise ValueError(f"map patch: {exc}") from None
    if peak_share > 0.0:
        g = _thin(g, peak_share)
    return g


def _thin(g: BuiltGrid, share: float, radius: float = PATCH_PEAK_RADIUS) -> BuiltGrid:
    """``g`` without the occupied cells whose hits are below ``share`` of the most hit cell
    within ``radius`` m of them (at least one cell; the fringe of a wall drawn from
    slightly different poses); such a cell is free when a beam passed it, else unknown."""
    import dataclasses

    r = max(1, int(round(radius / float(g.resolution))))
    h = g.hits.astype(np.float64)
    pad = np.pad(h, r)
    rows, cols = h.shape
    span = range(2 * r + 1)
    peak = np.max([pad[dy : dy + rows, dx : dx + cols] for dy in span for dx in span], axis=0)
    occupied = g.occupied & (h >= share * peak)
    free = (g.passes > 0) & ~occupied
    return dataclasses.replace(g, occupied=occupied, free=free)


def patch_grid(stretches: Sequence[Stretch], **options: Any) -> BuiltGrid | None:
    """The recorded scans of ``stretches`` ray-cast at their corrected poses
    (:func:`grid_from_scans`; ``refine``: re-chained by :func:`refined_poses` first, a
    stretch back in the map by :func:`graph_poses`, with ``walls``: its scans also matched
    against the mapped walls they see). A stretch not back in the map is left out unless
    ``include_open`` (:func:`in_patch`). None when no stretch put a scan in. The options
    (``resolution``, ``align``, ``mounting``, ``refine``, ``walls``, ``peak_share``,
    ``include_open``) and their defaults are :func:`patch_solution`'s, without sigmas."""
    return patch_solution(stretches, **options, sigmas=False)[0]


def patch_solution(
    stretches: Sequence[Stretch],
    *,
    resolution: float = PATCH_RESOLUTION,
    align: tuple[float, float] = (0.0, 0.0),
    mounting: Pose = (0.0, 0.0, 0.0),
    refine: bool = True,
    walls: MappedWalls | None = None,
    peak_share: float = PATCH_PEAK_SHARE,
    include_open: bool = False,
    sigmas: bool = True,
) -> tuple[BuiltGrid | None, NDArray[np.float64] | None]:
    """:func:`patch_grid` and, with ``sigmas``, per cell how surely its walls lie where
    they are drawn (:func:`cell_sigmas` [m]; from the pose graph's marginal covariances,
    inf where a scan's pose has none)."""
    scans: list[NDArray[np.float64]] = []
    poses: list[NDArray[np.float64]] = []
    covs: list[NDArray[np.float64] | None] = []
    for st in stretches:
        if not in_patch(st, include_open):
            continue
        scans.extend(pts for _, pts, _ in st.scans)
        x, c = _stretch_solution(st, refine, walls, marginals=sigmas)
        poses.extend(x)
        covs.extend(c)
    g = grid_from_scans(
        scans, poses, resolution=resolution, align=align, mounting=mounting,
        peak_share=peak_share,
    )  # fmt: skip
    if g is None or not sigmas:
        return g, None
    return g, cell_sigmas(g, scans, poses, covs)


def confidence_record(
    grid: BuiltGrid, sigma: NDArray[np.float64], bound: float = PATCH_SIGMA_BOUND
) -> dict[str, Any]:
    """What the patch YAML says of its walls' confidence (``icploc_patch_confidence``):
    the bound, its wall cells, how many of them are confident (sigma at most ``bound``:
    :data:`PATCH_SIGMA_BOUND`) and the sigma image's encoding."""
    sg = sigma[grid.occupied]
    return {
        "sigma_bound_m": float(bound),
        "wall_cells": int(grid.occupied.sum()),
        "confident_wall_cells": int(np.sum(sg <= bound)),
        "sigma_unit_m": PATCH_SIGMA_UNIT,
        "sigma_none": PATCH_SIGMA_NONE,
    }


def sigma_image(sigma: NDArray[np.float64]) -> NDArray[np.uint8]:
    """The cells' sigmas as grey levels (:data:`PATCH_SIGMA_UNIT` each, rounded up, so a
    level within :data:`PATCH_SIGMA_BOUND` is a cell within it; a finite sigma at most
    one level below :data:`PATCH_SIGMA_NONE`, that level where none), rows as the grid's (row 0 at the origin)."""
    q = np.clip(np.ceil(sigma / PATCH_SIGMA_UNIT - 1e-6), 0, PATCH_SIGMA_NONE - 1)
    return np.where(np.isfinite(sigma), q, PATCH_SIGMA_NONE).astype(np.uint8)


def read_sigma_image(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """A patch's ``.sigma.pgm`` back as sigmas [m] (row 0 at the origin; NaN for
    :data:`PATCH_SIGMA_NONE`). :class:`icploc.errors.MapError` naming the file unless it
    is a whole binary 8-bit PGM (P5, maxval 255)."""
    from icploc.maps.errors import MapError
    from icploc.maps.ros import _read_grey_u8

    p = Path(path)
    img = _read_grey_u8(p, p, None)
    if img is None:
        raise MapError(
            p, None, "not a binary 8-bit PGM (P5, maxval 255), or its header is cut short"
        )
    img = img[::-1]
    return np.where(img == PATCH_SIGMA_NONE, np.nan, img.astype(np.float64) * PATCH_SIGMA_UNIT)


def in_patch(st: Stretch, include_open: bool = False) -> bool:
    """Whether the patch draws ``st``'s scans: a stretch that locked again has its poses
    checked at both ends (the exit and the lock) and corrected between them; one not back
    in the map is dead reckoning nothing checked (real logs: aces' last stretch 35 cm off
    at its median scan, freiburg-101's 24 cm; leaving them out: aces 76 -> 80 %,
    freiburg-101 42 -> 53 % of the patch's walls within 10 cm), so it is drawn only with
    ``include_open``. A stretch that was a kidnap (:attr:`Stretch.jumped`: begun by a jump
    off the map, locked beyond its dead reckoning's uncertainty) never is: its poses are
    the dead reckoning of a place the robot was not."""
    if st.jumped:
        return False
    return bool(st.scans) and (include_open or (st.lock_pose is not None and st.correction is not None))


def patch_record(stretches: Sequence[Stretch], include_open: bool = False) -> list[dict[str, Any]]:
    """Per stretch what the patch made of it (the ``icploc_patch_stretches`` list of a
    patch's YAML): its first scan, scans recorded, metres coasted, whether it came back
    into the map (and the lock's correction [m]), whether its scans are in the patch and
    whether it was left out as a kidnap."""
    out: list[dict[str, Any]] = []
    for st in stretches:
        c = st.correction
        out.append(
            {
                "first_scan": int(st.start),
                "scans": len(st.scans),
                "coasted_m": round(float(st.distance), 3),
                "back_in_map": st.end is not None,
                "correction_m": None if c is None else round(math.hypot(c[0], c[1]), 3),
                "in_patch": in_patch(st, include_open),
                # left out as a kidnap (OutsideConfig.jump_*), not for being still open
                "kidnap": bool(st.jumped),
            }
        )
        if st.patch_placement is not None and in_patch(st, include_open):
            out[-1]["placement"] = dict(st.patch_placement)
    return out


def patch_layout(map_: Any) -> tuple[float, tuple[float, float]]:
    """(resolution, cell alignment) of a patch for ``map_``: a grid map's own, else
    :data:`PATCH_RESOLUTION` on multiples of it."""
    res = getattr(map_, "resolution", None)
    origin = getattr(map_, "origin", None)
    if getattr(map_, "grid", None) is not None and res and origin is not None:
        return float(res), (float(origin[0]), float(origin[1]))
    return PATCH_RESOLUTION, (0.0, 0.0)


def patch_outputs(path: str | os.PathLike[str]) -> dict[str, Path]:
    """The files ``--map-patch PATH`` writes (for the output checks made before a run);
    :class:`icploc.outputs.OutputError` unless PATH is a ``.yaml``."""
    from icploc.outputs import OutputError

    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        raise OutputError(f"--map-patch {p}: a map patch is a map_server .yaml file")
    return {
        "--map-patch": p,
        "--map-patch image": p.with_suffix(".pgm"),
        "--map-patch sigma image": sigma_path(p),
    }


def sigma_path(patch: str | os.PathLike[str]) -> Path:
    """The sigma image written beside a patch's YAML (``patch.yaml`` -> ``patch.sigma.pgm``)."""
    return Path(patch).with_suffix(".sigma.pgm")


def write_patch(
    path: str | os.PathLike[str],
    stretches: Sequence[Stretch],
    map_: Any = None,
    *,
    mounting: Pose = (0.0, 0.0, 0.0),
    walls: MappedWalls | None = None,
    include_open: bool = False,
    confident_only: bool = False,
    sigmas: bool = True,
) -> BuiltGrid | None:
    """Write the patch of ``stretches`` as a map_server YAML + PGM at ``path`` (a ``.yaml``)
    in ``map_``'s cell layout (``walls``, ``include_open``: see :func:`patch_grid`); the
    YAML also lists per stretch what the patch made of it (``icploc_patch_stretches``,
    :func:`patch_record`) and how sure its walls are (``icploc_patch_confidence``,
    :func:`confidence_record`), and a grey image beside it (:func:`sigma_path`,
    :func:`sigma_image`) says per cell the sigma of where its walls are drawn.
    ``confident_only``: a wall cell less sure than :data:`PATCH_SIGMA_BOUND` is left
    unknown (the merged map keeps what it knew there). ``sigmas`` False: no marginal
    covariances are computed (the pose graph's costliest part), so neither the sigma
    image nor the confidence record is written (and ``confident_only`` is an error).
    Returns the grid written (None and nothing written without a scan to draw)."""
    import yaml

    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        raise ValueError(f"--map-patch {p}: a map patch is a map_server .yaml file")
    if confident_only and not sigmas:
        raise ValueError("map patch: confident_only needs the sigmas (sigmas=True)")
    res, align = patch_layout(map_)
    g, sigma = patch_solution(
        stretches, resolution=res, align=align, mounting=mounting, walls=walls,
        include_open=include_open, sigmas=sigmas,
    )  # fmt: skip
    if g is None:
        return None
    record: dict[str, Any] = {"icploc_patch_stretches": patch_record(stretches, include_open)}
    if sigma is not None:
        conf = confidence_record(g, sigma)
        if confident_only:
            import dataclasses

            unsure = g.occupied & ~(sigma <= PATCH_SIGMA_BOUND)
            g = dataclasses.replace(g, occupied=g.occupied & ~unsure, free=g.free & ~unsure)
            conf["uncertain_left_unknown"] = True
        img = np.ascontiguousarray(sigma_image(sigma)[::-1])
        with open(sigma_path(p), "wb") as fh:
            fh.write(f"P5\n# icploc patch sigma, {PATCH_SIGMA_UNIT} m per level\n".encode("ascii"))
            fh.write(f"{img.shape[1]} {img.shape[0]}\n255\n".encode("ascii"))
            fh.write(img.tobytes())
        record["icploc_patch_confidence"] = conf
    g.save(p)
    with open(p, "a", encoding="utf-8") as fh:
        fh.write(yaml.safe_dump(record, sort_keys=False))
    return g
