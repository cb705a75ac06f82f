"""Issue 14: a damaged log replays to the end, with (nearly) every scan and the clean
log's accuracy; ``strict`` refuses it; the summary says what was dropped."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from icploc import sim as worlds
from icploc.logs import LogFormatError, write_carmen
from icploc.maps import Map
from icploc.messages import Scan
from icploc.replay import replay
from icploc.trajectory import tum_line
from log_damage import damage


@pytest.fixture(scope="module", params=["FLASER", "ROBOTLASER1"])
def logs(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> dict:
    d = tmp_path_factory.mktemp("damage")
    w = worlds.lab(people=2)
    path = worlds.lab_random_walk(20.0, seed=21)
    frames = list(worlds.simulate(w, path, seed=22, noise=0.02, max_frames=600))
    clean = d / "clean.log"
    write_carmen(
        clean,
        [f.scan for f in frames],
        [f.odometry for f in frames],
        poses=[f.truth for f in frames],
        scan_odometry=[f.odometry.pose for f in frames],
        precision=3,
        fmt=request.param,
    )
    truth = d / "truth.tum"
    truth.write_text("".join(tum_line(f.scan.stamp, f.truth) for f in frames))
    dm = damage(clean.read_text(), np.random.default_rng(3))
    bad = d / "damaged.log"
    bad.write_bytes(dm.data)
    m = Map.from_lines(w.lines).to_ros(d / "lab.yaml", 0.05)
    return {
        "dir": d,
        "frames": frames,
        "clean": clean,
        "bad": bad,
        "damage": dm,
        "truth": truth,
        "map": m,
        "clean_res": replay(clean, m, truth=truth),
        "bad_res": replay(bad, m, truth=truth),
    }


def test_damaged_log_keeps_at_least_97_percent_of_its_scans(logs: dict) -> None:
    assert logs["bad_res"].scans >= 0.97 * logs["clean_res"].scans


def test_damaged_log_loses_exactly_the_unreadable_scans(logs: dict) -> None:
    assert logs["bad_res"].scans == len(logs["frames"]) - len(logs["damage"].lost_scans)


def test_damaged_log_has_the_accuracy_of_the_clean_log(logs: dict) -> None:
    c, b = logs["clean_res"].metrics, logs["bad_res"].metrics
    # the damaged log loses 1 % of the beams and 6 scans: within 1 mm of the clean p95 / max
    assert b["ate_p95_m"] <= c["ate_p95_m"] + 0.001
    assert b["ate_max_m"] <= c["ate_max_m"] + 0.001


def test_damaged_log_is_never_lost(logs: dict) -> None:
    assert logs["bad_res"].status_counts.get("lost", 0) == 0


def test_damaged_log_doubts_no_more_scans_than_the_clean_log(logs: dict) -> None:
    # the clean log has a few `degraded` (unverified) scans of its own, where people hide walls
    bad, clean = logs["bad_res"].status_counts, logs["clean_res"].status_counts
    assert bad.get("degraded", 0) <= clean.get("degraded", 0)


def test_damaged_log_summary_lists_the_dropped_lines(logs: dict) -> None:
    first = sorted(logs["damage"].malformed_lines)[:10]
    text = logs["bad_res"].summary()
    listed = [int(p.split(":")[0]) for p in text.split("line ")[1:] if p.split(":")[0].isdigit()]
    assert listed == first


def test_damaged_log_summary_counts_the_invalid_readings(logs: dict) -> None:
    inv = logs["bad_res"].log_info.invalid_readings
    assert set(inv) == {"NaN", "negative", "beyond max range"}


def test_strict_replay_refuses_the_damaged_log_at_a_damaged_line(logs: dict) -> None:
    with pytest.raises(LogFormatError) as ei:
        replay(logs["bad"], logs["map"], truth=logs["truth"], strict=True)
    assert ei.value.line in logs["damage"].malformed_lines


def test_one_negative_reading_does_not_stop_the_replay(logs: dict, tmp_path: Path) -> None:
    """Issue 14: a 90 m log with a -0.01 m reading stopped at that line, writing nothing."""
    lines = logs["clean"].read_text().split("\n")
    k = [i for i, ln in enumerate(lines) if ln.startswith(("FLASER", "ROBOTLASER1"))][300]
    t = lines[k].split(" ")
    t[100] = "-0.01"
    lines[k] = " ".join(t)
    p = tmp_path / "neg.log"
    p.write_text("\n".join(lines))
    out = tmp_path / "t.tum"
    res = replay(p, logs["map"], truth=logs["truth"], out=out)
    assert (res.scans, len(out.read_text().splitlines())) == (len(logs["frames"]),) * 2


def test_nan_scan_stamp_in_memory_is_dropped_and_counted(logs: dict) -> None:
    """Issue 14: a NaN scan stamp returned `tracking`, then the next update raised a bare
    numpy ValueError."""
    fr = logs["frames"][:80]
    items: list = []
    for k, f in enumerate(fr):
        s = f.scan
        if k == 40:
            s = Scan(math.nan, s.ranges, s.angles, s.flags, s.seq, s.max_range)
        items.extend([f.odometry, s])
    res = replay(items, Map.load(logs["map"]), initial_pose=fr[0].truth)
    assert (res.scans, res.dropped_stamps, res.status_counts) == (79, 1, {"tracking": 79})


def test_nan_scan_stamp_in_memory_refused_when_strict(logs: dict) -> None:
    fr = logs["frames"][:10]
    items: list = [f.odometry for f in fr] + [Scan(math.nan, fr[0].scan.ranges, fr[0].scan.angles)]
    with pytest.raises(ValueError, match="non-finite stamp"):
        replay(items, Map.load(logs["map"]), initial_pose=fr[0].truth, strict=True)


def test_nan_scan_stamp_in_a_file_is_repaired(logs: dict) -> None:
    info = logs["bad_res"].log_info
    assert (info.stamps, info.n_repaired_stamps) == ("repaired", logs["damage"].nan_stamps)
