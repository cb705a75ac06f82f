"""--state: the last verified pose survives a restart, and is checked before it is trusted."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from icploc import sim as worlds
from icploc.localizer import Estimate, Localizer, Status
from icploc.maps import Map
from icploc.replay import replay
from icploc.state import (
    SavedState,
    StateError,
    StateSaver,
    load_state,
    restore,
    save_state,
    write_state,
)

#: the global localization's documented budget in the lab: a verified lock within 5 scans
GLOBAL_BUDGET_SCANS = 5


@pytest.fixture(scope="module")
def lab() -> dict:
    """A lab run cut in two at scan 100: the restart happens there."""
    w = worlds.lab(people=1)
    frames = list(worlds.simulate(w, worlds.lab_random_walk(12.0, seed=8), seed=9, max_frames=220))
    items = sorted([f.scan for f in frames] + [f.odometry for f in frames], key=lambda m: m.stamp)
    cut = frames[100].scan.stamp
    return {
        "map": Map.from_lines(w.lines),
        "frames": frames,
        "first": [m for m in items if m.stamp < cut],
        "second": [m for m in items if m.stamp >= cut],
        "truth_second": np.array([f.truth for f in frames[100:]]),
    }


def _err(est: Estimate, truth: np.ndarray) -> float:
    return math.hypot(est.pose[0] - truth[0], est.pose[1] - truth[1])


def _first_half(lab: dict, path: Path) -> StateSaver:
    """Run the first half from the true start, saving the state as ``icploc run`` does
    (every estimate to a :class:`StateSaver`, closed at the end)."""
    f0 = lab["frames"][0]
    res = replay(lab["first"], lab["map"], initial_pose=f0.truth)
    saver = StateSaver(Localizer(lab["map"], initial_pose=f0.truth), path, every=1.0)
    for e in res.estimates:
        saver.observe(e)
    saver.close()
    return saver


def _first_half_state(lab: dict, path: Path) -> Path:
    return _first_half(lab, path).path


def test_restart_with_the_right_state_tracks_from_the_first_scan(lab: dict, tmp_path: Path) -> None:
    state = _first_half_state(lab, tmp_path / "state.json")
    checks = []
    res = replay(
        lab["second"], lab["map"], on_localizer=lambda loc: checks.append(restore(loc, state))
    )
    assert (checks[0].verdict, res.estimates[0].status) == ("accepted", Status.TRACKING)


def test_restart_with_the_right_state_is_accurate_from_the_first_scan(
    lab: dict, tmp_path: Path
) -> None:
    state = _first_half_state(lab, tmp_path / "state.json")
    res = replay(lab["second"], lab["map"], on_localizer=lambda loc: restore(loc, state))
    errs = [_err(e, t) for e, t in zip(res.estimates, lab["truth_second"], strict=True)]
    assert max(errs) < 0.05


def _wrong_state(lab: dict, path: Path) -> Path:
    # the robot was carried 3 m and turned while switched off: the saved pose is wrong
    t = lab["frames"][100].truth
    wrong = (t[0] - 3.0, t[1] + 1.0, t[2] + 1.2)
    write_state(path, SavedState(wrong, np.diag([1e-4, 1e-4, 1e-4]), 0.0))
    return path


def test_restart_with_a_wrong_state_is_not_trusted(lab: dict, tmp_path: Path) -> None:
    state = _wrong_state(lab, tmp_path / "state.json")
    checks = []
    res = replay(
        lab["second"], lab["map"], on_localizer=lambda loc: checks.append(restore(loc, state))
    )
    assert (checks[0].verdict, res.estimates[0].status) == ("rejected", Status.LOST)


def test_restart_with_a_wrong_state_tracks_within_the_global_budget(
    lab: dict, tmp_path: Path
) -> None:
    state = _wrong_state(lab, tmp_path / "state.json")
    res = replay(lab["second"], lab["map"], on_localizer=lambda loc: restore(loc, state))
    first = next(i for i, e in enumerate(res.estimates) if e.status is Status.TRACKING)
    assert first < GLOBAL_BUDGET_SCANS
    errs = [_err(e, t) for e, t in zip(res.estimates, lab["truth_second"], strict=True)]
    assert max(errs[first:]) < 0.05


def test_a_slightly_pushed_robot_is_corrected_on_the_first_scan(lab: dict, tmp_path: Path) -> None:
    t = lab["frames"][100].truth
    state = tmp_path / "state.json"
    write_state(state, SavedState((t[0] + 0.2, t[1] - 0.1, t[2] + 0.05), np.eye(3) * 1e-4, 0.0))
    res = replay(lab["second"], lab["map"], on_localizer=lambda loc: restore(loc, state))
    assert (res.estimates[0].status, _err(res.estimates[0], lab["truth_second"][0]) < 0.05) == (
        Status.TRACKING,
        True,
    )


def test_saved_state_is_the_last_tracking_estimate(lab: dict, tmp_path: Path) -> None:
    f0 = lab["frames"][0]
    res = replay(lab["first"], lab["map"], initial_pose=f0.truth)
    last = [e for e in res.estimates if e.status is Status.TRACKING][-1]
    st = load_state(_first_half_state(lab, tmp_path / "s.json"))
    assert (st.pose, st.stamp) == (tuple(last.pose), last.stamp)
    assert np.array_equal(st.covariance, last.covariance)


def test_saves_once_per_second_of_scan_time(lab: dict, tmp_path: Path) -> None:
    saves = _first_half(lab, tmp_path / "s.json").saves
    stamps = [f.scan.stamp for f in lab["frames"][:100]]
    span = stamps[-1] - stamps[0]
    # one at the start, one per second after, one at close for the newest
    assert int(span) + 1 <= saves <= int(span) + 2


def test_nothing_saved_without_a_tracking_estimate(lab: dict, tmp_path: Path) -> None:
    loc = Localizer(lab["map"])  # no pose: lost
    assert (save_state(loc, tmp_path / "s.json"), (tmp_path / "s.json").exists()) == (None, False)


def test_localizer_methods_round_trip(lab: dict, tmp_path: Path) -> None:
    f0 = lab["frames"][0]
    loc = Localizer(lab["map"], initial_pose=f0.truth)
    loc.update(f0.scan, f0.odometry)
    loc.save_state(tmp_path / "s.json")
    other = Localizer(lab["map"])
    check = other.load_state(tmp_path / "s.json")
    assert (other.pose, other.status, check.verdict) == (loc.pose, Status.LOST, "")


def test_write_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    p = tmp_path / "s.json"
    write_state(p, SavedState((1.0, 2.0, 0.5), np.eye(3) * 0.01, 1.0))
    before = p.read_bytes()

    def fail(src: str, dst: str) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError):
        write_state(p, SavedState((5.0, 6.0, 0.1), np.eye(3) * 0.01, 2.0))
    assert (p.read_bytes(), sorted(x.name for x in tmp_path.iterdir())) == (before, ["s.json"])


def test_saver_reports_a_failed_write_once_and_goes_on(lab: dict, tmp_path: Path) -> None:
    loc = Localizer(lab["map"], initial_pose=(1.0, 1.0, 0.0))
    msgs: list[str] = []
    s = StateSaver(loc, tmp_path / "missing" / "s.json", every=0.0, on_error=msgs.append)
    e = Estimate(0.0, (1.0, 1.0, 0.0), np.eye(3) * 1e-4, Status.TRACKING, 1.0, 3, 0.0)
    for k in range(3):
        s.observe(Estimate(float(k), e.pose, e.covariance, e.status, 1.0, 3, 0.0))
    assert (len(msgs), s.saves) == (1, 0)


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("not json", "invalid JSON"),
        ('{"format": "other"}', "format"),
        ('{"format": "icploc-state", "version": 9}', "version"),
        ('{"format": "icploc-state", "version": 1, "pose": [1, 2]}', "'pose'"),
        ('{"format": "icploc-state", "version": 1, "pose": [1, 2, "x"]}', "'pose'"),
        (
            '{"format": "icploc-state", "version": 1, "pose": [1, 2, 3], '
            '"covariance": [[1, 0, 0], [0, -1, 0], [0, 0, 1]]}',
            "'covariance'",
        ),
        (
            '{"format": "icploc-state", "version": 1, "pose": [1, 2, 3], "covariance": [1]}',
            "'covariance'",
        ),
    ],
)
def test_bad_state_file_is_a_clear_error(tmp_path: Path, text: str, field: str) -> None:
    p = tmp_path / "s.json"
    p.write_text(text)
    with pytest.raises(StateError, match=rf"{p}.*{field}"):
        load_state(p)


def test_run_hooks_restore_and_save(lab: dict, tmp_path: Path) -> None:
    """What ``icploc run --state FILE`` does: restore at start, save while tracking."""
    from icploc.hooks import RunHooks

    state = _first_half_state(lab, tmp_path / "state.json")
    before = json.loads(state.read_text())["stamp"]
    hooks = RunHooks(state=state)
    res = replay(lab["second"], lab["map"], on_localizer=hooks.on_localizer)
    for e in res.estimates:
        hooks.observe(e)
    hooks.close()
    after = load_state(state)
    assert (hooks.check.verdict, after.stamp > before, after.stamp) == (
        "accepted",
        True,
        res.estimates[-1].stamp,
    )


def test_run_hooks_warn_about_a_bad_state_and_go_global(lab: dict, tmp_path: Path) -> None:
    from icploc.hooks import RunHooks

    state = tmp_path / "state.json"
    state.write_text("{")
    msgs: list[str] = []
    hooks = RunHooks(state=state, warn=msgs.append)
    res = replay(lab["second"], lab["map"], on_localizer=hooks.on_localizer)
    hooks.close()
    assert (len(msgs), "invalid JSON" in msgs[0], res.estimates[-1].status) == (
        1,
        True,
        Status.TRACKING,
    )


def test_run_hooks_say_when_the_saved_pose_is_rejected(lab: dict, tmp_path: Path) -> None:
    from icploc.hooks import RunHooks

    state = _wrong_state(lab, tmp_path / "state.json")
    msgs: list[str] = []
    hooks = RunHooks(state=state, warn=msgs.append)
    res = replay(lab["second"], lab["map"], on_localizer=hooks.on_localizer)
    for e in res.estimates:
        hooks.observe(e)
    hooks.close()
    assert msgs == [f"{state}: the saved pose does not match the first scan; localizing globally"]
