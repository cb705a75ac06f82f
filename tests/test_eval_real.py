"""The fast parts of the real-data benchmark (benches/eval_real.py): the odometry error
model fit, the sparsifier, the rasteriser, the map / localize split, the metrics and the
MRPT gridmap patch. The benchmark itself runs the localizers; these check its measuring
stick."""

from __future__ import annotations

import gzip
import math
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

BENCHES = Path(__file__).resolve().parent.parent / "benches"
sys.path.insert(0, str(BENCHES))

import real_grid as rg  # noqa: E402
import real_logs as rl  # noqa: E402
import real_metrics as rm  # noqa: E402
import real_mrpt  # noqa: E402
import real_odometry as ro  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
MOTIONS = SHARED / "freiburg_course"
needs_shared = pytest.mark.skipif(
    not (MOTIONS / "odom_motions.dat").exists(), reason="../shared/data not present"
)


# --------------------------------------------------------------------------- odometry model


def _synthetic_pairs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Truth steps (forward 0.1-0.3 m, some turning) and odometry with a known +2 % scale,
    −5 % rotation scale, 0.6°/m heading bias and small Gaussian noise."""
    rng = np.random.default_rng(seed)
    dx = rng.uniform(0.1, 0.3, n)
    dth = np.where(rng.random(n) < 0.3, rng.uniform(-0.3, 0.3, n), rng.normal(0, 0.002, n))
    truth = np.column_stack([dx, rng.normal(0, 0.002, n), dth])
    odom = np.column_stack(
        [
            1.02 * truth[:, 0] + rng.normal(0, 0.002, n),
            truth[:, 1] + rng.normal(0, 0.002, n),
            0.95 * truth[:, 2] + math.radians(0.6) * dx + rng.normal(0, 0.0005, n),
        ]
    )
    return odom, truth


@pytest.fixture(scope="module")
def synthetic_model(tmp_path_factory: pytest.TempPathFactory) -> ro.OdometryErrorModel:
    odom, truth = _synthetic_pairs(3000, seed=7)
    d = tmp_path_factory.mktemp("motions")
    np.savetxt(d / "odom.dat", odom)
    np.savetxt(d / "truth.dat", truth)
    return ro.fit_model(ro.load_motions(d / "odom.dat"), ro.load_motions(d / "truth.dat"))


def test_fit_recovers_known_distance_scale(synthetic_model: ro.OdometryErrorModel) -> None:
    assert synthetic_model.scale == pytest.approx(0.02, abs=0.002)


def test_fit_recovers_known_rotation_scale(synthetic_model: ro.OdometryErrorModel) -> None:
    assert synthetic_model.turn_scale == pytest.approx(-0.05, abs=0.005)


def test_fit_recovers_known_heading_bias(synthetic_model: ro.OdometryErrorModel) -> None:
    assert math.degrees(synthetic_model.bias) == pytest.approx(0.6, abs=0.1)


def test_fit_bank_is_standardised(synthetic_model: ro.OdometryErrorModel) -> None:
    bank = np.asarray(synthetic_model.bank)
    assert np.std(bank, axis=0) == pytest.approx([1.0, 1.0, 1.0], abs=0.25)


def test_load_motions_names_the_file_on_a_bad_table(tmp_path: Path) -> None:
    p = tmp_path / "two_columns.dat"
    p.write_text("0.1 0.0\n0.1 0.0\n")
    with pytest.raises(ValueError, match="two_columns.dat"):
        ro.load_motions(p)


def test_apply_model_is_reproducible_per_seed(synthetic_model: ro.OdometryErrorModel) -> None:
    ref = ro.compose_steps(np.zeros(3), np.tile([0.2, 0.0, 0.05], (100, 1)))
    a = ro.apply_model(synthetic_model, ref, seed=3)
    b = ro.apply_model(synthetic_model, ref, seed=3)
    assert np.array_equal(a, b)


def test_apply_model_without_motion_adds_no_error(synthetic_model: ro.OdometryErrorModel) -> None:
    ref = np.tile([1.0, 2.0, 0.5], (20, 1))
    assert np.allclose(ro.apply_model(synthetic_model, ref, seed=1), ref)


def test_worse_base_has_larger_systematic_errors(synthetic_model: ro.OdometryErrorModel) -> None:
    bad = synthetic_model.worse()
    assert (abs(bad.scale), abs(bad.bias), abs(bad.turn_scale)) > (
        abs(synthetic_model.scale),
        abs(synthetic_model.bias),
        abs(synthetic_model.turn_scale),
    )


@pytest.mark.shared_data
@needs_shared
def test_real_fit_reproduces_the_real_odometry_drift() -> None:
    """Applied to the scan-matched path, the model fitted to the 2,000 real pairs drifts
    about as far as the real wheel odometry did over it (22 m after 331 m)."""
    odom = ro.load_motions(MOTIONS / "odom_motions.dat")
    truth = ro.load_motions(MOTIONS / "scanmatched_motions.dat")
    model = ro.fit_model(odom, truth)
    path = ro.compose_steps(np.zeros(3), truth)
    real_end = np.hypot(*(ro.compose_steps(np.zeros(3), odom)[-1, :2] - path[-1, :2]))
    sim_end = [np.hypot(*(ro.apply_model(model, path, seed=s)[-1, :2] - path[-1, :2])) for s in range(5)]
    assert 0.5 * real_end < float(np.median(sim_end)) < 2.0 * real_end


@pytest.mark.shared_data
@pytest.mark.skipif(not (SHARED / "radish_corrected_logs").exists(), reason="../shared/data not present")
def test_each_unseen_log_is_one_file_of_180_degree_scans_with_a_reference_path() -> None:
    """The logs no one tuned on (eval_real.UNSEEN_LOGS): each name finds exactly one log,
    its FLASER scans cover 180 degrees at 1 or 0.5 degree steps, and its corrected path is
    long enough to cut into the three folds."""
    import eval_real as ev

    for name in ev.UNSEEN_LOGS:
        (path,) = ev.find_logs(SHARED, [name])
        log = rl.read_flaser(path)
        assert log.ranges.shape[1] in (180, 181, 360, 361)
        assert math.degrees(log.angles[-1] - log.angles[0]) == pytest.approx(180.0, abs=1.01)
        travelled = float(np.sum(np.hypot(*np.diff(log.poses[:, :2], axis=0).T)))
        assert len(log) > 200 and travelled > 150.0, name


# --------------------------------------------------------------------------- sparsifier


def test_sparsify_keeps_one_scan_per_half_metre() -> None:
    poses = np.column_stack([np.arange(101) * 0.1, np.zeros(101), np.zeros(101)])
    assert rl.sparsify(poses, distance=0.5, angle=0.5).tolist() == list(range(0, 101, 5))


def test_sparsify_keeps_one_scan_per_half_radian_turned_in_place() -> None:
    poses = np.column_stack([np.zeros(21), np.zeros(21), np.arange(21) * 0.1])
    assert rl.sparsify(poses, distance=0.5, angle=0.5).tolist() == [0, 5, 10, 15, 20]


def test_sparsify_period_keeps_a_standing_robot_every_two_seconds() -> None:
    poses = np.zeros((11, 3))
    stamps = np.arange(11) * 0.5
    assert rl.sparsify(poses, stamps, period=2.0).tolist() == [0, 4, 8]


# --------------------------------------------------------------------------- rasteriser


def _room_scans(poses: np.ndarray, n: int = 360) -> np.ndarray:
    """Exact ranges in a 4 m x 4 m room (walls x, y = 0 and 4) from each pose."""
    ang = rl.beam_angles(n)
    out = np.empty((len(poses), n))
    for k, p in enumerate(poses):
        a = p[2] + ang
        c, s = np.cos(a), np.sin(a)
        with np.errstate(divide="ignore"):
            tx = np.where(c > 0, (4 - p[0]) / c, np.where(c < 0, -p[0] / c, np.inf))
            ty = np.where(s > 0, (4 - p[1]) / s, np.where(s < 0, -p[1] / s, np.inf))
        out[k] = np.minimum(tx, ty)
    return out


@pytest.fixture(scope="module")
def room() -> rg.Grid:
    """Two places, four headings each: every wall cell is seen by at least two scans (the
    rasteriser's ``min_hits``)."""
    poses = np.array([[x, x, h] for x in (1.5, 2.5) for h in (0.0, math.pi / 2, math.pi, -math.pi / 2)])
    return rg.rasterise(_room_scans(poses), rl.beam_angles(360), poses, 0.1, max_range=30.0)


def test_rasterised_walls_lie_on_the_walls(room: rg.Grid) -> None:
    c = room.occupied_centres()
    to_wall = np.minimum.reduce([np.abs(c[:, 0]), np.abs(c[:, 0] - 4), np.abs(c[:, 1]), np.abs(c[:, 1] - 4)])
    assert to_wall.max() <= 0.1


def test_rasterised_walls_are_closed(room: rg.Grid) -> None:
    """Every 10 cm of each wall holds an occupied cell."""
    c = room.occupied_centres()
    along = np.arange(0.05, 4.0, 0.1)
    gaps = 0
    for fixed, axis in ((0.0, 0), (4.0, 0), (0.0, 1), (4.0, 1)):
        on = c[np.abs(c[:, axis] - fixed) <= 0.1]
        other = on[:, 1 - axis]
        gaps += int(sum(np.min(np.abs(other - t)) > 0.1 for t in along))
    assert gaps == 0


def test_rasterised_room_interior_is_free(room: rg.Grid) -> None:
    r0 = int((0.3 - room.origin[1]) / room.resolution)
    r1 = int((3.7 - room.origin[1]) / room.resolution)
    c0 = int((0.3 - room.origin[0]) / room.resolution)
    c1 = int((3.7 - room.origin[0]) / room.resolution)
    assert room.free[r0:r1, c0:c1].all()


def test_rasterised_outside_is_unknown(room: rg.Grid) -> None:
    r = int((4.5 - room.origin[1]) / room.resolution)
    assert not room.free[r].any() and not room.occupied[r].any()


def test_map_server_round_trip_keeps_cells_and_origin(room: rg.Grid, tmp_path: Path) -> None:
    back = rg.read_map_server(rg.write_map_server(room, tmp_path / "room.yaml"))
    assert (np.array_equal(back.occupied, room.occupied), back.origin) == (True, pytest.approx(room.origin))


def test_map_server_pgm_has_highest_y_in_the_top_row(tmp_path: Path) -> None:
    occ = np.zeros((3, 2), dtype=bool)
    occ[2, 0] = True  # highest y row
    grid = rg.Grid(occupied=occ, free=~occ, resolution=0.1, origin=(0.0, 0.0))
    rg.write_map_server(grid, tmp_path / "m.yaml")
    raw = (tmp_path / "m.pgm").read_bytes()
    pixels = np.frombuffer(raw[-6:], dtype=np.uint8).reshape(3, 2)
    assert pixels[0, 0] == rg.OCC


def test_rasteriser_ignores_no_return_beams() -> None:
    poses = np.array([[2.0, 2.0, 0.0]])
    ranges = np.full((1, 360), 81.9)  # all saturation values
    grid = rg.rasterise(ranges, rl.beam_angles(360), poses, 0.1, max_range=30.0)
    assert not grid.occupied.any()


# --------------------------------------------------------------------------- split


def test_localized_scans_never_map_their_own_fold() -> None:
    """Two laps of a 10 m square, 0.1 m apart: in every fold no localized scan (nor its
    neighbours) is in the map."""
    t = np.linspace(0, 2, 801)[:-1]
    pos = np.column_stack([10 * np.abs(((t * 4) % 2) - 1), 10 * np.abs((((t * 4) + 0.5) % 2) - 1)])
    poses = np.column_stack([pos, np.zeros(len(pos))])
    ends = [p[None, :2] + [[1.0, 0.0]] for p in poses]
    kept = rl.sparsify(poses)
    leaks = 0
    for f in rl.split_folds(pos, 3, gap=10):
        map_idx, loc, _ = rl.map_scans_for(f, ends, kept)
        leaks += len(np.intersect1d(map_idx, np.concatenate([loc - 1, loc, loc + 1])))
    assert leaks == 0


def test_write_then_read_flaser_keeps_ranges_and_odometry(tmp_path: Path) -> None:
    ranges = np.array([[1.0, 2.5, 81.91], [3.25, 0.5, 4.0]])
    odom = np.array([[0.1, 0.2, 0.3], [1.1, -0.2, -3.0]])
    rl.write_flaser(tmp_path / "x.log", ranges, odom, np.array([1.0, 2.0]))
    back = rl.read_flaser(tmp_path / "x.log")
    assert (np.allclose(back.ranges, ranges), np.allclose(back.odom, odom), np.allclose(back.poses, odom)) == (True, True, True)


def test_read_flaser_names_the_line_of_a_truncated_scan(tmp_path: Path) -> None:
    p = tmp_path / "bad.log"
    p.write_text("FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.0 h 1.0\nFLASER 3 1.0 2.0\n")
    with pytest.raises(ValueError, match=r"bad.log:2"):
        rl.read_flaser(p)


# --------------------------------------------------------------------------- metrics


def _ref_and_est(offsets: list[float]) -> tuple[np.ndarray, np.ndarray]:
    ref = np.column_stack([np.arange(len(offsets), dtype=float), np.zeros(len(offsets)), np.zeros(len(offsets))])
    est = ref.copy()
    est[:, 1] += offsets
    return est, ref


def test_false_tracking_counts_only_claimed_scans_far_off() -> None:
    est, ref = _ref_and_est([0.1, 0.2, 0.6, 1.0])
    s = rm.summarise(est, ref, ["tracking", "tracking", "tracking", "lost"])
    assert s["false_tracking"] == 1


def test_a_peer_without_status_claims_every_scan() -> None:
    est, ref = _ref_and_est([0.1, 0.2, 0.6, 1.0])
    assert rm.summarise(est, ref, None)["false_tracking"] == 2


def test_error_percentiles() -> None:
    est, ref = _ref_and_est([0.1, 0.2, 0.6, 1.0])
    s = rm.summarise(est, ref, None)
    assert (s["median_m"], s["max_m"]) == (pytest.approx(0.4), pytest.approx(1.0))


def test_a_nan_estimate_counts_as_infinitely_wrong() -> None:
    est, ref = _ref_and_est([0.1, 0.2, 0.3])
    est[1, 0] = math.nan
    assert rm.summarise(est, ref, None)["max_m"] == math.inf


def test_map_fit_is_zero_on_the_map_and_capped_off_it() -> None:
    ang = np.array([0.0])
    wall = np.array([[2.0, 0.0]])
    est = np.array([[0.0, 0.0, 0.0], [0.0, 5.0, 0.0]])
    fit = rm.map_fit(est, np.array([[2.0], [2.0]]), ang, wall, max_range=10.0, cap=1.0)
    assert fit.tolist() == [0.0, 1.0]


# --------------------------------------------------------------------------- MRPT glue


def _fake_gridmap(path: Path) -> None:
    name = b"mrpt::maps::COccupancyGridMap2D"
    head = b"\x9f" + name + b"\x06\x08" + struct.pack("<IIfffff", 40, 30, -1.0, 1.0, -0.5, 1.0, 0.05)
    cells = b"\x81" * 1200
    opts = struct.pack("<iffffIf", 4, 0.35, 0.95, 0.05, 81.0, 5, 0.3)  # method, stdHit .. maxCorrs
    with gzip.open(path, "wb") as f:
        f.write(head + cells + b"\x00" * 8 + opts)


def test_gridmap_patch_overrides_the_likelihood_options(tmp_path: Path) -> None:
    src, dst = tmp_path / "m.gridmap.gz", tmp_path / "p.gridmap.gz"
    _fake_gridmap(src)
    real_mrpt._patch_gridmap(src, dst, max_range=30.0, decimation=3)
    raw = gzip.open(dst).read()
    i = raw.find(struct.pack("<f", real_mrpt.LF["std"]))
    got = struct.unpack_from("<ffffIf", raw, i)
    assert got == pytest.approx((0.2, 0.95, 0.05, 30.0, 3, 0.3), abs=1e-6)


def test_gridmap_patch_reads_back_the_rounded_origin(tmp_path: Path) -> None:
    src, dst = tmp_path / "m.gridmap.gz", tmp_path / "p.gridmap.gz"
    _fake_gridmap(src)
    assert real_mrpt._patch_gridmap(src, dst, 30.0, 3) == (-1.0, -0.5)


def test_gridmap_patch_refuses_an_unknown_layout(tmp_path: Path) -> None:
    src = tmp_path / "m.gridmap.gz"
    with gzip.open(src, "wb") as f:
        f.write(b"\x9fmrpt::maps::COccupancyGridMap2D" + b"\x00" * 64)
    with pytest.raises(ValueError, match="not found once"):
        real_mrpt._patch_gridmap(src, tmp_path / "p.gridmap.gz", 30.0, 3)


@pytest.mark.parametrize("n", [180, 181, 360, 361])
def test_mrpt_fan_matches_carmen_beam_angles(n: int) -> None:
    """MRPT spreads N beams symmetrically over resolution * N about the laser's yaw: with
    the PARAM and the yaw offset written, its beams are CARMEN's."""
    step, yaw = real_mrpt._fan(n)
    aperture = step * (n - 1)
    mrpt = yaw - aperture / 2 + np.arange(n) * aperture / (n - 1)
    assert np.allclose(mrpt, rl.beam_angles(n))


def _cell(method: str, med: float, p95: float, mx: float, log: str = "intel") -> dict:
    return {"log": log, "map_res_m": 0.05, "base": "good", "method": method,
            "median_m": med, "p95_m": p95, "max_m": mx}  # fmt: skip


def test_targets_compare_each_figure_with_the_best_peer_in_the_cell() -> None:
    from eval_real import targets

    rows = [
        _cell("icploc", 0.03, 0.10, 0.20),
        _cell("mrpt", 0.04, 0.12, 0.50),
        _cell("numpy", 0.02, 0.20, 0.30),  # best median and best max are numpy's
    ]
    line = next(ln for ln in targets(rows, peer=None) if ln.startswith("| intel"))
    # max 20 <= half of numpy's 30? no; p95 10 <= 75 % of mrpt's 12? no; median 3 <= numpy's 2? no
    assert line.endswith("| no | no | no |")


def test_targets_against_a_named_peer_ignore_the_others() -> None:
    from eval_real import targets

    rows = [
        _cell("icploc", 0.03, 0.08, 0.10),
        _cell("mrpt", 0.04, 0.12, 0.25),
        _cell("numpy", 0.01, 0.05, 0.05),  # better on every figure, but not the named peer
    ]
    line = next(ln for ln in targets(rows, peer="mrpt") if ln.startswith("| intel"))
    assert line.endswith("| yes | yes | yes |")


def test_targets_count_the_cells_that_meet_them() -> None:
    from eval_real import targets

    rows = [
        _cell("icploc", 0.03, 0.08, 0.10),
        _cell("mrpt", 0.04, 0.12, 0.25),
        _cell("icploc", 0.03, 0.10, 0.20, log="aces"),
        _cell("mrpt", 0.04, 0.12, 0.25, log="aces"),
    ]
    total = next(ln for ln in targets(rows) if "cells meeting it" in ln)
    assert total.endswith("| 1 / 2 | 1 / 2 | 2 / 2 |")
