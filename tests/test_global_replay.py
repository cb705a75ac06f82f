"""Replays without an initial pose localize globally; a kidnapping in the middle of a
replayed (simulated) run is detected and recovered."""

from __future__ import annotations

import math

import numpy as np
import pytest
from icploc import sim as worlds
from icploc.config import LocalizerConfig
from icploc.localizer import Localizer, Status, run
from icploc.maps import Map
from icploc.messages import Odometry, Scan
from icploc.relocalize import attach
from icploc.replay import replay
from icploc.se2 import between, compose, wrap_angle


@pytest.fixture(scope="module")
def lab_run() -> dict:
    w = worlds.lab(people=2)
    frames = list(worlds.simulate(w, worlds.lab_random_walk(8.0, seed=21), seed=22, max_frames=150))
    return {"world": w, "frames": frames, "map": Map.from_lines(w.lines)}


def _items(frames: list) -> list:
    out: list = []
    for f in frames:
        out += [f.odometry, f.scan]
    return out


def _err(a, b) -> tuple[float, float]:
    return math.hypot(a[0] - b[0], a[1] - b[1]), abs(wrap_angle(a[2] - b[2]))


@pytest.mark.parametrize("forced", [False, True])
def test_replay_without_initial_pose_localizes_globally(lab_run: dict, forced: bool) -> None:
    frames = lab_run["frames"]
    truth = None
    if forced:  # truth given (for the metrics) but not used to start
        truth = (np.array([f.scan.stamp for f in frames]), np.array([f.truth for f in frames]))
    res = replay(_items(frames), lab_run["map"], truth=truth, global_localize=forced)
    ests = res.estimates
    assert len(ests) == len(frames)
    first = next(k for k, e in enumerate(ests) if e.status is Status.TRACKING)
    assert first < 5, [e.status.value for e in ests[:8]]
    for e, f in zip(ests[first:], frames[first:], strict=True):
        de, dth = _err(e.pose, f.truth)
        assert de < 0.1 and dth < math.radians(3.0), (e, f.truth)
    assert res.status_counts.get("tracking", 0) > 0.9 * len(frames)
    if forced:
        assert res.metrics  # the truth still scores the run


def test_kidnap_in_the_middle_of_a_replayed_run(lab_run: dict) -> None:
    w = lab_run["world"]
    a = lab_run["frames"][:60]
    end = a[-1].truth
    cx, cy = max(
        ((x, y) for x in (-2.0, 2.0) for y in (-2.2, 2.2)),
        key=lambda c: math.hypot(c[0] - end[0], c[1] - end[1]),
    )
    cy = max(-2.2, min(cy, 1.2))  # the circle (radius 1, north of its start) stays inside
    b = list(
        worlds.simulate(
            w,
            worlds.circle_path(radius=1.0, laps=1, center=(cx, cy)),
            start=(cx, cy, 0.0),
            seed=5,
            max_frames=60,
        )
    )
    # carried to the lab corner farthest from where run a ends (3.9 m here; the global
    # benchmark carries >= 5 m)
    # splice: the robot is carried from the end of run a to the start of run b; the wheel
    # odometry continues from where it was with run b's increments (it felt nothing)
    items: list = []
    truth: list = []
    odo = a[-1].odometry.pose
    dt = a[1].scan.stamp - a[0].scan.stamp
    t_end = a[-1].scan.stamp
    for f in a:
        items += [f.odometry, f.scan]
        truth.append(f.truth)
    for k, f in enumerate(b):
        if k:
            odo = compose(odo, between(b[k - 1].odometry.pose, f.odometry.pose))
        t = t_end + (k + 1) * dt
        s = f.scan
        items.append(Odometry(stamp=t, pose=odo))
        items.append(
            Scan(stamp=t, ranges=s.ranges, angles=s.angles, flags=s.flags, max_range=s.max_range)
        )
        truth.append(f.truth)
    loc = Localizer(lab_run["map"], LocalizerConfig(), initial_pose=a[0].truth)
    attach(loc)
    ests = run(loc, items)
    n = len(a)
    for e, p in zip(ests[:n], truth[:n], strict=True):
        assert e.status is not Status.LOST and _err(e.pose, p)[0] < 0.1
    after = list(zip(ests[n:], truth[n:], strict=True))
    lost = next(k for k, (e, _) in enumerate(after) if e.status is Status.LOST)
    back = next(
        k
        for k, (e, p) in enumerate(after)
        if k > lost
        and e.status is Status.TRACKING
        and _err(e.pose, p)[0] <= 0.05
        and _err(e.pose, p)[1] <= math.radians(1.0)
    )
    assert back < 20, (lost, back, b[0].truth, a[-1].truth)
    # once back, it stays with the truth
    for e, p in after[back:]:
        assert _err(e.pose, p)[0] < 0.1


def test_a_crowd_is_not_a_kidnapping() -> None:
    """12 people circling the robot collapse the inlier ratio (the lost detector fires) but
    no pose elsewhere explains the scans convincingly: tracking goes on, nothing is lost."""
    w = worlds.crowd(people=12)
    path = worlds.tour_path(worlds.lab_random_walk(20.0, seed=13), laps=2)
    frames = list(worlds.simulate(w, path, seed=1, noise=0.02, speed=0.6, max_frames=700))
    loc = Localizer(Map.from_lines(w.lines), LocalizerConfig(), initial_pose=frames[0].truth)
    attach(loc)
    ests = run(loc, _items(frames))
    assert all(e.status is not Status.LOST for e in ests)
    assert max(_err(e.pose, f.truth)[0] for e, f in zip(ests, frames, strict=True)) < 0.05


def test_replay_in_a_symmetric_room_reports_ambiguity() -> None:
    """A replay without an initial pose in a perfectly symmetric room: never a lock, and
    the summary says the lost scans were ambiguous rather than simply lost."""
    room = worlds.World("room", np.array(worlds.rect(0.0, 0.0, 8.0, 5.0)))
    path = worlds.circle_path(radius=1.0, laps=1, center=(4.0, 2.5))
    frames = list(worlds.simulate(room, path, start=(4.0, 2.5, 0.0), seed=3, max_frames=30))
    res = replay(_items(frames), Map.from_lines(room.lines))
    assert all(e.status is Status.LOST for e in res.estimates)
    amb = sum(e.reason == "ambiguous" for e in res.estimates)
    assert amb >= len(frames) - 3, [e.reason for e in res.estimates]
    assert f"{amb} of them ambiguous" in res.summary()
