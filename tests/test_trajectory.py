"""Trajectories: TUM I/O, association, ATE and RPE."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from icploc.trajectory import (
    Trajectory,
    TrajectoryFormatError,
    align_se2,
    associate,
    ate,
    read_tum,
    rpe,
    wrap,
    write_tum,
)


def _circle(n: int = 200, r: float = 2.0, dt: float = 0.1) -> Trajectory:
    t = np.arange(n) * dt
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return Trajectory.from_poses(
        t, np.column_stack((r * np.cos(a), r * np.sin(a), wrap(a + np.pi / 2)))
    )


finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@st.composite
def trajectories(draw: st.DrawFn, min_size: int = 1) -> Trajectory:
    n = draw(st.integers(min_size, 40))
    stamps = np.cumsum(draw(arrays(np.float64, n, elements=st.floats(0.001, 10.0)))) + draw(
        st.floats(0.0, 1e6)
    )
    xy = draw(arrays(np.float64, (n, 2), elements=finite))
    th = draw(arrays(np.float64, n, elements=st.floats(-math.pi + 1e-6, math.pi - 1e-6)))
    return Trajectory(stamps, np.column_stack((xy, th)))


# ----------------------------------------------------------------------------- TUM


def test_tum_format_is_2d(tmp_path: Path) -> None:
    p = tmp_path / "t.tum"
    write_tum(p, Trajectory(np.array([1.5]), np.array([[1.0, 2.0, math.pi / 2]])))
    rows = [r for r in p.read_text().splitlines() if not r.startswith("#")]
    v = [float(x) for x in rows[0].split()]
    assert len(v) == 8
    assert v[:4] == [1.5, 1.0, 2.0, 0.0] and v[4] == 0.0 and v[5] == 0.0
    assert v[6] == pytest.approx(math.sin(math.pi / 4)) and v[7] == pytest.approx(
        math.cos(math.pi / 4)
    )


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(tr=trajectories())
def test_tum_round_trip(tmp_path: Path, tr: Trajectory) -> None:
    p = tmp_path / "rt.tum"
    write_tum(p, tr)
    back = read_tum(p)
    assert np.allclose(back.stamps, tr.stamps, rtol=0, atol=1e-9)
    assert np.allclose(back.xy, tr.xy, rtol=0, atol=1e-8)
    assert np.allclose(np.abs(wrap(back.theta - tr.theta)), 0.0, atol=1e-7)


def test_read_tum_accepts_3d_files_and_comments(tmp_path: Path) -> None:
    p = tmp_path / "x.tum"
    q = (0.0, 0.0, math.sin(0.3), math.cos(0.3))  # yaw 0.6
    p.write_text(f"# hdr\n\n1.0 2 3 0.5 {q[0]} {q[1]} {q[2]} {q[3]}\n2.0,3,4,0,0,0,0,1\n")
    t = read_tum(p)
    assert len(t) == 2
    assert t.theta[0] == pytest.approx(0.6) and t.theta[1] == 0.0


@pytest.mark.parametrize(
    ("row", "msg"),
    [
        ("1 2 3 0 0 0 0", "expected 8 values"),
        ("1 2 3 0 0 0 zz 1", "not a number"),
        ("1 2 nan 0 0 0 0 1", "non-finite"),
        ("1 2 3 0 0 0 0 2", "quaternion norm"),
    ],
)
def test_read_tum_malformed(tmp_path: Path, row: str, msg: str) -> None:
    p = tmp_path / "bad.tum"
    p.write_text("0 0 0 0 0 0 0 1\n" + row + "\n")
    with pytest.raises(TrajectoryFormatError, match=msg) as ei:
        read_tum(p)
    assert ei.value.line == 2 and str(ei.value).startswith(f"{p}:2:")


def test_trajectory_validation() -> None:
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        Trajectory(np.zeros(3), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="finite"):
        Trajectory(np.zeros(1), np.array([[np.nan, 0, 0]]))


# ----------------------------------------------------------------------------- association


def test_associate_nearest_and_interpolate() -> None:
    ref = Trajectory(np.array([0.0, 1.0, 2.0]), np.array([[0, 0, 3.0], [1, 0, -3.0], [2, 2, 0.0]]))
    est = Trajectory(np.array([0.5, 1.01, 5.0]), np.zeros((3, 3)))
    a = associate(est, ref, method="nearest", max_dt=0.02)
    assert list(a.stamps) == [1.01] and a.n_unmatched == 2
    assert np.allclose(a.ref[0], [1, 0, -3.0])
    b = associate(est, ref, method="interpolate", max_dt=0.02)
    assert list(b.stamps) == [0.5, 1.01] and b.n_unmatched == 1
    # theta interpolates across ±pi along the short arc
    assert b.ref[0][0] == pytest.approx(0.5)
    assert abs(b.ref[0][2]) == pytest.approx(math.pi, abs=1e-9)


def test_interpolation_refuses_large_gaps() -> None:
    ref = Trajectory(np.array([0.0, 10.0]), np.zeros((2, 3)))
    _, ok = ref.at([5.0], method="interpolate", max_gap=1.0)
    assert not ok[0]
    _, ok = ref.at([5.0], method="interpolate", max_gap=20.0)
    assert ok[0]


# ----------------------------------------------------------------------------- ATE


@settings(max_examples=40, deadline=None)
@given(tr=trajectories(), align=st.booleans())
def test_ate_of_identical_is_zero(tr: Trajectory, align: bool) -> None:
    r = ate(tr, tr, align=align)
    assert r.n == len(tr)
    assert r.position.max < 1e-6 and r.heading.max < 1e-9


@settings(max_examples=40, deadline=None)
@given(tr=trajectories(min_size=2), seed=st.integers(0, 2**32 - 1))
def test_ate_invariant_to_order(tr: Trajectory, seed: int) -> None:
    rng = np.random.default_rng(seed)
    noisy = Trajectory(tr.stamps, tr.poses + rng.normal(0, 0.1, tr.poses.shape))
    perm = rng.permutation(len(tr))
    shuffled = Trajectory(noisy.stamps[perm], noisy.poses[perm])
    a = ate(noisy, tr)
    b = ate(shuffled, Trajectory(tr.stamps[perm[::-1]], tr.poses[perm[::-1]]))
    assert a.position.rmse == pytest.approx(b.position.rmse, rel=1e-12, abs=1e-15)
    assert a.heading.max == pytest.approx(b.heading.max, rel=1e-12, abs=1e-15)


def test_ate_known_offset_and_stats() -> None:
    ref = _circle()
    est = Trajectory(ref.stamps, ref.poses + [0.03, -0.04, 0.01])
    r = ate(est, ref)
    assert r.position.rmse == pytest.approx(0.05) and r.position.max == pytest.approx(0.05)
    assert r.position.median == pytest.approx(0.05) and r.position.p95 == pytest.approx(0.05)
    assert r.heading.rmse == pytest.approx(0.01)
    assert "5.00 cm" in r.summary()


def test_ate_percentiles() -> None:
    ref = Trajectory(np.arange(100.0), np.zeros((100, 3)))
    err = np.arange(100.0) / 100.0
    est = Trajectory(ref.stamps, np.column_stack((err, np.zeros(100), np.zeros(100))))
    r = ate(est, ref)
    assert r.position.median == pytest.approx(np.median(err))
    assert r.position.p95 == pytest.approx(np.percentile(err, 95))
    assert r.position.max == pytest.approx(0.99)
    assert r.position.rmse == pytest.approx(math.sqrt(np.mean(err**2)))


def test_ate_with_alignment_removes_rigid_transform() -> None:
    ref = _circle()
    T = (1.0, -2.0, 0.7)
    est = ref.transformed(T)
    assert ate(est, ref).position.rmse > 1.0
    r = ate(est, ref, align=True)
    assert r.position.max < 1e-9 and r.heading.max < 1e-9
    # the alignment maps est back onto ref: it is the inverse of T
    back = est.transformed(r.alignment)
    assert np.allclose(back.xy, ref.xy)


def test_align_se2_recovers_transform() -> None:
    rng = np.random.default_rng(2)
    a = rng.normal(size=(50, 2))
    th = -2.5
    c, s = math.cos(th), math.sin(th)
    b = a @ np.array([[c, s], [-s, c]]) + [3.0, 4.0]
    x, y, t = align_se2(a, b)
    assert (x, y, t) == pytest.approx((3.0, 4.0, th))


def test_ate_no_overlap_raises() -> None:
    a = Trajectory(np.array([0.0]), np.zeros((1, 3)))
    b = Trajectory(np.array([100.0]), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="no estimate"):
        ate(a, b)


# ----------------------------------------------------------------------------- RPE


def test_rpe_zero_for_rigidly_moved_copy() -> None:
    ref = _circle()
    est = ref.transformed((5.0, 1.0, 1.2))  # a map-frame offset does not change motions
    r = rpe(est, ref, delta=0.5)
    assert r.n > 0 and r.translation.max < 1e-9 and r.rotation.max < 1e-9


def test_rpe_measures_scale_drift() -> None:
    t = np.arange(101) * 0.1
    ref = Trajectory.from_poses(t, np.column_stack((t, np.zeros(101), np.zeros(101))))
    est = Trajectory.from_poses(t, np.column_stack((1.1 * t, np.zeros(101), np.zeros(101))))
    r = rpe(est, ref, delta=1.0, unit="m")
    assert r.translation.median == pytest.approx(0.1, rel=1e-6)
    r2 = rpe(est, ref, delta=2.0, unit="s")
    assert r2.translation.median == pytest.approx(0.2, rel=1e-6)
    assert r.rotation.max == 0.0


def test_rpe_rotation_error() -> None:
    t = np.arange(50) * 1.0
    ref = Trajectory.from_poses(t, np.column_stack((t, np.zeros(50), np.zeros(50))))
    th = np.arange(50) * 0.01
    est = Trajectory.from_poses(t, np.column_stack((t, np.zeros(50), th)))
    r = rpe(est, ref, delta=5.0, unit="s")
    assert r.rotation.median == pytest.approx(0.05)


def test_rpe_bad_args() -> None:
    tr = _circle(10)
    with pytest.raises(ValueError):
        rpe(tr, tr, delta=0.0)
    with pytest.raises(ValueError):
        rpe(tr, tr, unit="km")  # type: ignore[arg-type]
    assert rpe(tr, tr, delta=1e6).n == 0


def test_path_length_and_sorted() -> None:
    tr = Trajectory(np.array([2.0, 0.0, 1.0]), np.array([[2, 0, 0], [0, 0, 0], [1, 0, 0.0]]))
    assert tr.path_length() == pytest.approx(2.0)
    assert list(tr.sorted().stamps) == [0.0, 1.0, 2.0]


# ----------------------------------------------------------------------------- streaming writers


def test_tum_writer_rows_are_on_disk_before_close(tmp_path: Path) -> None:
    from icploc.trajectory import TumWriter

    p = tmp_path / "t.tum"
    w = TumWriter(p, flush_every=0.0)
    for k in range(5):
        w.write(0.1 * k, (k, -k, 0.1 * k))
    on_disk = len(p.read_text().splitlines())
    w.close()
    assert on_disk == 5


def test_tum_writer_output_reads_back(tmp_path: Path) -> None:
    from icploc.trajectory import TumWriter

    p = tmp_path / "t.tum"
    with TumWriter(p) as w:
        for k in range(5):
            w.write(0.1 * k, (k, -k, 0.3 * k))
    tr = read_tum(p)
    assert np.allclose(tr.poses, [(k, -k, 0.3 * k) for k in range(5)], atol=1e-6)


def test_estimates_writer_row_per_estimate(tmp_path: Path) -> None:
    import csv
    from types import SimpleNamespace

    from icploc.trajectory import ESTIMATE_COLUMNS, EstimatesWriter

    e = SimpleNamespace(
        stamp=1.5, pose=(1.0, 2.0, 0.5), status=SimpleNamespace(value="degraded"),
        reason="jump, far", inlier_ratio=0.5, covariance=np.diag([1e-4, 2e-4, 3e-4]),
        accepted=False, iterations=7, num_points=300, degeneracy=0.9,
    )  # fmt: skip
    p = tmp_path / "e.csv"
    with EstimatesWriter(p) as w:
        w.write(e)
        w.write(e)
    rows = list(csv.DictReader(p.read_text().splitlines()))
    assert [tuple(rows[0]), len(rows), rows[1]["reason"], rows[1]["cov_tt"]] == [
        ESTIMATE_COLUMNS, 2, "jump, far", "0.0003",
    ]  # fmt: skip


# ----------------------------------------------------------------------------- one layer


def test_write_tum_starts_with_the_header_and_reads_back(tmp_path: Path) -> None:
    from icploc.trajectory import TUM_HEADER

    p = tmp_path / "h.tum"
    tr = _circle(10)
    write_tum(p, tr)
    back = read_tum(p)
    assert (p.read_text().startswith(TUM_HEADER), np.allclose(back.poses, tr.poses, atol=1e-8)) == (
        True,
        True,
    )


def test_tum_line_is_what_the_writers_write(tmp_path: Path) -> None:
    from icploc.trajectory import TumWriter, tum_line

    p = tmp_path / "w.tum"
    with TumWriter(p) as w:
        w.write(1.25, (1.0, -2.0, 0.5))
    assert p.read_text() == tum_line(1.25, (1.0, -2.0, 0.5))


def test_tum_writer_on_an_open_file_leaves_it_open(tmp_path: Path) -> None:
    from icploc.trajectory import TumWriter

    p = tmp_path / "f.tum"
    with open(p, "w", encoding="ascii") as fh:
        w = TumWriter(fh)
        w.write(0.0, (0.0, 0.0, 0.0))
        w.close()
        fh.write("# after\n")
    assert p.read_text().splitlines()[1] == "# after"


class _FullDisk:
    name = "full.tum"
    closed = False

    def write(self, text: str) -> int:
        raise OSError(28, "No space left on device")

    def flush(self) -> None:
        pass


def test_tum_writer_can_stop_instead_of_raising() -> None:
    from icploc.trajectory import TumWriter

    w = TumWriter(_FullDisk(), on_error="stop", name="--out")  # type: ignore[arg-type]
    w.write(0.0, (0.0, 0.0, 0.0))
    w.write(0.1, (0.0, 0.0, 0.0))
    assert (w.rows, w.error) == (0, "--out: writing stopped: No space left on device")


def test_tum_writer_raises_by_default() -> None:
    from icploc.trajectory import TumWriter

    w = TumWriter(_FullDisk())  # type: ignore[arg-type]
    with pytest.raises(OSError, match="No space"):
        w.write(0.0, (0.0, 0.0, 0.0))


def test_started_at_keeps_the_motion_and_moves_the_start() -> None:
    tr = _circle(50)
    start = (5.0, -1.0, 0.7)
    moved = tr.started_at(start)
    steps = [_rel(a, b) for a, b in zip(tr.poses[:-1], tr.poses[1:], strict=True)]
    moved_steps = [_rel(a, b) for a, b in zip(moved.poses[:-1], moved.poses[1:], strict=True)]
    assert np.allclose(moved.poses[0], start) and np.allclose(steps, moved_steps, atol=1e-9)


def _rel(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return (c * dx + s * dy, -s * dx + c * dy, float(wrap(b[2] - a[2])))


def test_pose_errors_wrap_the_heading() -> None:
    from icploc.trajectory import pose_errors

    pos, hd = pose_errors([[3.0, 4.0, math.pi - 0.1]], [[0.0, 0.0, -math.pi + 0.1]])
    assert (float(pos[0]), round(float(hd[0]), 9)) == (5.0, 0.2)


def test_pose_errors_refuse_unpaired_arrays() -> None:
    from icploc.trajectory import pose_errors

    with pytest.raises(ValueError, match="2 estimates for 1 reference"):
        pose_errors(np.zeros((2, 3)), np.zeros((1, 3)))


def test_evaluate_interpolates_the_truth_and_names_its_figures() -> None:
    from icploc.trajectory import evaluate

    ref = _circle(200)
    est = Trajectory(ref.stamps[10:-10] + 0.05, ref.at(ref.stamps[10:-10] + 0.05)[0] + [0.02, 0, 0])
    ev = evaluate(est, ref)
    assert ev is not None
    m = ev.metrics()
    assert sorted(m) == [
        "ate_max_m", "ate_median_m", "ate_p95_m", "ate_rmse_m", "heading_max_deg", "rpe_1m_rmse_m",
    ]  # fmt: skip
    assert m["ate_rmse_m"] == pytest.approx(0.02, abs=1e-9)


def test_evaluate_without_overlap_is_none() -> None:
    from icploc.trajectory import evaluate

    ref = _circle(20)
    est = Trajectory(ref.stamps + 100.0, ref.poses)
    assert evaluate(est, ref) is None
