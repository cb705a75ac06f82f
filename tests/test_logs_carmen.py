"""CARMEN log reader/writer: round trips, angle conventions, gzip, stamps, malformed input,
and the real logs in ../shared/data (skipped when absent)."""

from __future__ import annotations

import gzip
import logging
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from icploc.logs import LogFormatError, detect_format, log_info, open_log
from icploc.logs._base import repair_stamps
from icploc.logs.carmen import flaser_angles, read_carmen, write_carmen
from icploc.messages import BEAM_INVALID, BEAM_NO_RETURN, Odometry, Scan

SHARED = Path(__file__).parents[1] / ".." / "shared" / "data"
needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data not present")


def _scans(
    n_scans: int, n_beams: int, *, t0: float = 10.0, dt: float = 0.2, seed: int = 0
) -> list[Scan]:
    rng = np.random.default_rng(seed)
    ang = flaser_angles(n_beams)
    out = []
    for k in range(n_scans):
        r = np.round(rng.uniform(0.2, 7.5, n_beams), 3)
        r[rng.random(n_beams) < 0.1] = np.inf
        out.append(Scan(stamp=t0 + k * dt, ranges=r, angles=ang, max_range=8.0))
    return out


def _odoms(n: int, *, t0: float = 10.0, dt: float = 0.05) -> list[Odometry]:
    return [
        Odometry(
            stamp=t0 + k * dt,
            pose=(0.01 * k, -0.02 * k, math.remainder(0.03 * k, 2 * math.pi)),
            velocity=(0.2, 0.1),
        )
        for k in range(n)
    ]


# ----------------------------------------------------------------------------- conventions


@pytest.mark.parametrize(
    ("n", "first", "last", "step"),
    [
        (180, -90.0, 89.0, 1.0),
        (360, -90.0, 89.5, 0.5),
        (181, -90.0, 90.0, 1.0),
        (361, -90.0, 90.0, 0.5),
    ],
)
def test_flaser_angle_conventions(n: int, first: float, last: float, step: float) -> None:
    a = np.degrees(flaser_angles(n))
    assert len(a) == n
    assert a[0] == pytest.approx(first, abs=1e-9)
    assert a[-1] == pytest.approx(last, abs=1e-9)
    assert np.allclose(np.diff(a), step)


def test_flaser_angles_in_read_scans(tmp_path: Path) -> None:
    for n in (180, 181, 360, 361):
        p = tmp_path / f"a{n}.log"
        p.write_text(f"FLASER {n} " + " ".join(["1.5"] * n) + " 0 0 0 0 0 0 1.0 host 1.0\n")
        d = read_carmen(p)
        assert len(d.scans) == 1
        assert np.allclose(d.scans[0].angles, flaser_angles(n))
        assert math.degrees(d.scans[0].angles[0]) == pytest.approx(-90.0)


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("gz", [False, True])
def test_round_trip_flaser(tmp_path: Path, gz: bool) -> None:
    scans = _scans(30, 361)
    odoms = _odoms(120)
    poses = np.column_stack((np.arange(30) * 0.1, np.arange(30) * -0.05, np.linspace(-1, 1, 30)))
    odo_at = poses + 0.01
    p = tmp_path / ("r.log.gz" if gz else "r.log")
    write_carmen(p, scans, odoms, poses=poses, scan_odometry=odo_at)
    if gz:
        assert p.read_bytes()[:2] == b"\x1f\x8b"
    d = read_carmen(p)
    assert d.info.format == "carmen"
    assert d.info.stamps == "ok"
    assert len(d.scans) == 30 and len(d.odometry) == 120
    for a, b in zip(scans, d.scans, strict=True):
        assert b.stamp == a.stamp
        assert np.array_equal(np.isinf(a.ranges), np.isinf(b.ranges))
        fin = np.isfinite(a.ranges)
        np.testing.assert_allclose(b.ranges[fin], a.ranges[fin], rtol=1e-15)
        assert b.flags is not None
        assert np.array_equal((b.flags & BEAM_NO_RETURN) != 0, ~fin)
        assert b.max_range == 8.0
    for oa, ob in zip(odoms, d.odometry, strict=True):
        assert ob.stamp == oa.stamp and ob.pose == pytest.approx(oa.pose)
        assert ob.velocity == pytest.approx(oa.velocity)
    assert np.allclose(d.truth_poses, poses)
    assert np.allclose(d.truth_stamps, [s.stamp for s in scans])
    assert np.allclose(d.scan_odometry, odo_at)  # exposed even though ODOM lines are used
    assert [s.seq for s in d.scans] == list(range(30))
    # open_log yields both kinds in time order, odometry first on equal stamps
    msgs = list(open_log(p))
    assert len(msgs) == 150
    st_ = [m.stamp for m in msgs]
    assert st_ == sorted(st_)
    first_scan = next(i for i, m in enumerate(msgs) if isinstance(m, Scan))
    assert (
        isinstance(msgs[first_scan - 1], Odometry)
        and msgs[first_scan - 1].stamp == msgs[first_scan].stamp
    )


def test_embedded_odometry_used_without_odom_lines(tmp_path: Path) -> None:
    scans = _scans(5, 180)
    odo_at = np.column_stack((np.arange(5.0), np.zeros(5), np.full(5, 0.5)))
    p = tmp_path / "e.log"
    write_carmen(p, scans, [], poses=np.zeros((5, 3)), scan_odometry=odo_at)
    d = read_carmen(p)
    assert len(d.odometry) == 5
    assert [o.pose for o in d.odometry] == [tuple(r) for r in odo_at]
    assert d.odometry[0].extra["source"] == "FLASER"
    assert [o.stamp for o in d.odometry] == [s.stamp for s in d.scans]
    assert read_carmen(p, odometry="none").odometry == []


def test_round_trip_robotlaser1(tmp_path: Path) -> None:
    ang = np.deg2rad(-119.5) + np.arange(681) * np.deg2rad(0.352)
    rng = np.random.default_rng(3)
    scans = [
        Scan(stamp=100.0 + k, ranges=rng.uniform(0.1, 5.0, 681), angles=ang, max_range=5.6)
        for k in range(4)
    ]
    scans[1].ranges[[3, 7]] = np.inf
    poses = rng.normal(size=(4, 3))
    robot = poses + [0.1, 0.0, 0.0]
    p = tmp_path / "rl.log"
    write_carmen(p, scans, [], poses=poses, scan_odometry=robot, fmt="ROBOTLASER1")
    d = read_carmen(p)
    assert len(d.scans) == 4
    assert np.allclose(d.scans[0].angles, ang)
    assert d.scans[0].max_range == 5.6
    assert np.isinf(d.scans[1].ranges[[3, 7]]).all()
    assert d.scans[1].flags is not None and d.scans[1].flags[3] & BEAM_NO_RETURN
    assert np.allclose(d.truth_poses, poses)
    assert np.allclose([o.pose for o in d.odometry], robot)
    assert d.odometry[0].extra["source"] == "ROBOTLASER1"
    assert any("offset from the robot pose" in n for n in d.info.notes)


def test_writer_rejects_non_flaser_angles(tmp_path: Path) -> None:
    s = Scan(stamp=0.0, ranges=np.ones(10), angles=np.linspace(-1, 1, 10))
    with pytest.raises(ValueError, match="FLASER convention"):
        write_carmen(tmp_path / "x.log", [s], [])


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    n=st.sampled_from([180, 181, 360, 361]),
    ranges=st.lists(st.floats(0.01, 79.0, allow_nan=False), min_size=1, max_size=1),
    stamp=st.floats(0.001, 2e9, allow_nan=False),
)
def test_round_trip_exact_values(tmp_path: Path, n: int, ranges: list[float], stamp: float) -> None:
    r = np.full(n, ranges[0])
    r[::7] = np.linspace(0.05, 70.0, len(r[::7]))
    s = Scan(stamp=stamp, ranges=r, angles=flaser_angles(n), max_range=80.0)
    p = tmp_path / "h.log"
    write_carmen(p, [s], [])
    d = read_carmen(p)
    assert d.scans[0].stamp == stamp
    np.testing.assert_allclose(d.scans[0].ranges, r, rtol=1e-15)


# ----------------------------------------------------------------------------- sentinels, NaN


def test_no_return_sentinel_detected_without_param(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    lines = []
    for k in range(60):
        r = np.round(rng.uniform(0.3, 20.0, 180), 2)
        r[rng.random(180) < 0.2] = 81.91
        lines.append(f"FLASER 180 {' '.join(map(str, r))} 0 0 0 0 0 0 {k + 1.0} h {k + 1.0}")
    p = tmp_path / "s.log"
    p.write_text("\n".join(lines) + "\n")
    d = read_carmen(p)
    assert d.info.max_range == pytest.approx(81.91 - 0.25)
    for s in d.scans:
        assert s.flags is not None
        assert np.array_equal(np.isinf(s.ranges), (s.flags & BEAM_NO_RETURN) != 0)
        assert np.all(s.ranges[np.isfinite(s.ranges)] <= 20.0)
    # an explicit max range wins
    d2 = read_carmen(p, max_range=10.0)
    assert all(np.all(s.ranges[np.isfinite(s.ranges)] < 10.0) for s in d2.scans)


def test_nan_ranges_invalid_or_error(tmp_path: Path) -> None:
    p = tmp_path / "n.log"
    p.write_text(
        "FLASER 3\t1.0\tNaN 2.0 0 0 0 0 0 0 0 0 name\nFLASER 3 1.0 1.5 nan 0 0 0 0 0 0 0 0 name\n"
    )
    d = read_carmen(p)
    s = d.scans[0]
    assert np.isinf(s.ranges[1]) and s.flags is not None and s.flags[1] & BEAM_INVALID
    assert not np.isnan(np.stack([x.ranges for x in d.scans])).any()
    with pytest.raises(LogFormatError, match=r"n\.log:1: NaN range"):
        read_carmen(p, nan_ranges="error")


def test_stuck_beam_flagged(tmp_path: Path) -> None:
    scans = [replace(s, max_range=80.0) for s in _scans(60, 181)]
    for s in scans:
        s.ranges[180] = 50.0
    p = tmp_path / "stuck.log"
    write_carmen(p, scans, [])
    d = read_carmen(p)
    assert all(s.flags is not None and s.flags[180] & BEAM_INVALID for s in d.scans)
    assert any("never change" in n for n in d.info.notes)
    d2 = read_carmen(p, stuck_beams=False)
    assert d2.scans[0].ranges[180] == 50.0


# ----------------------------------------------------------------------------- stamps


def _flaser(t: float, x: float = 0.0) -> str:
    return f"FLASER 3 1 2 3 {x} 0 0 {x} 0 0 {t} h {t}"


def test_all_zero_stamps_fall_back_to_index(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    p = tmp_path / "z.log"
    p.write_text("\n".join(_flaser(0.0, k) for k in range(10)) + "\n")
    with caplog.at_level(logging.INFO, logger="icploc.logs"):
        d = read_carmen(p, period=0.25)
    assert d.info.stamps == "synthetic"
    assert "zero" in d.info.stamp_note
    assert [s.stamp for s in d.scans] == pytest.approx([0.25 * k for k in range(10)])
    assert any("synthetic" in r.message for r in caplog.records)
    assert [o.pose[0] for o in d.odometry] == list(range(10))


def test_rounded_stamps_fall_back_to_index(tmp_path: Path) -> None:
    p = tmp_path / "r.log"
    p.write_text("\n".join(_flaser(1.13486e09 if k < 6 else 1.13487e09) for k in range(12)) + "\n")
    d = read_carmen(p)
    assert d.info.stamps == "synthetic"
    assert "distinct" in d.info.stamp_note
    assert np.all(np.diff([s.stamp for s in d.scans]) > 0)


def test_out_of_order_stamps_repaired_in_file_order(tmp_path: Path) -> None:
    t = [1.0 + 0.5 * k for k in range(20)]
    t[7] = 9.9  # one stamp jumps ahead
    t[12] = 2.0  # one jumps back
    p = tmp_path / "o.log"
    p.write_text("\n".join(_flaser(v, k) for k, v in enumerate(t)) + "\n")
    d = read_carmen(p)
    assert d.info.stamps == "repaired" and d.info.n_repaired_stamps == 2
    assert [o.pose[0] for o in d.odometry] == list(range(20))  # file order kept
    st_ = [s.stamp for s in d.scans]
    assert st_[7] == pytest.approx(4.5) and st_[12] == pytest.approx(7.0)
    assert np.all(np.diff(st_) > 0)
    raw = read_carmen(p, timestamps="raw")
    assert [s.stamp for s in raw.scans] == sorted(t)


def test_zero_stamped_odom_interpolated(tmp_path: Path) -> None:
    lines = [
        "ODOM 0 0 0 0 0 0 1.0 h 1.0",
        _flaser(1.5),
        "ODOM 1 0 0 0 0 0 0 h 0",
        "ODOM 2 0 0 0 0 0 2.0 h 2.0",
        _flaser(2.5),
    ]
    p = tmp_path / "zo.log"
    p.write_text("\n".join(lines) + "\n")
    d = read_carmen(p)
    assert [o.stamp for o in d.odometry] == pytest.approx([1.0, 1.75, 2.0])
    assert d.info.stamps == "repaired"
    assert not any("repeat the preceding laser pose" in n for n in d.info.notes)
    lines[2] = "ODOM 0 0 0 0 0 0 0 h 0"  # a copy of the FLASER's reported pose, unstamped
    p.write_text("\n".join(lines) + "\n")
    assert any("1 unstamped ODOM lines repeat" in n for n in read_carmen(p).info.notes)


def test_repair_stamps_monotone_scans() -> None:
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.01, 0.2, 500))
    bad = rng.choice(500, 20, replace=False)
    t[bad] = rng.uniform(0, 100, 20)
    t[rng.choice(500, 10, replace=False)] = 0.0
    is_scan = rng.random(500) < 0.5
    r = repair_stamps(t, is_scan)
    assert (
        r.status == "repaired"
    )  # 13 of ~250 scan stamps bad: under the 10 % that forces synthetic
    assert np.all(np.diff(r.stamps[is_scan]) >= 0)
    assert np.all(np.isfinite(r.stamps))
    r2 = repair_stamps(t, is_scan)
    assert np.array_equal(r.stamps, r2.stamps)


# ----------------------------------------------------------------------------- malformed


#: (damaged second line, strict error text, lenient outcome: "dropped" the line,
#: "invalid" reading (scan kept, beam invalid) or "repaired" stamp (scan kept))
MALFORMED = [
    ("FLASER 3 1 2 0 0 0 0 0 0 1.0 h 1.0", "truncated", "dropped"),
    ("FLASER 3 1 2 3 0 0 0 0 0 0 1.0 h 1.0 extra tokens", "tokens", "dropped"),
    ("FLASER x 1 2 3 0 0 0 0 0 0 1.0 h 1.0", "not an integer", "dropped"),
    ("FLASER 3 1 zz 3 0 0 0 0 0 0 1.0 h 1.0", "'zz' is not a number", "dropped"),
    ("FLASER 3 1 2 3 nan 0 0 0 0 0 1.0 h 1.0", "not finite", "dropped"),
    ("FLASER 3 1 2 3 0 0 0 0 0 0 NaN h 1.0", "not finite", "repaired"),
    ("FLASER 3 1 -2 3 0 0 0 0 0 0 1.0 h 1.0", "negative", "invalid"),
    ("FLASER 3 1 2e9 3 0 0 0 0 0 0 1.0 h 1.0", "beyond max range", "invalid"),
    ("FLASER 3 1 nan 3 0 0 0 0 0 0 1.0 h 1.0", "NaN range", "invalid"),
    ("FLASER", "truncated", "dropped"),
    ("FLASER 4 1 2 3 0 0 0 0 0 0 1.0 h 1.0", "truncated", "dropped"),
    ("\x93\xff\x00garbage\x01 \x85 binary", "not a CARMEN message", "dropped"),
    ("ODOM 0 0 0 0 0", "ODOM: truncated", "dropped"),
    ("ODOM 0 0 0 0 0 1.0 h 1.0", "ODOM: truncated", "dropped"),
    ("ODOM 0 0 0 0 q 0 1.0 h 1.0", "'q' is not a number", "dropped"),
    ("ODOM 0 0 nan 0 0 0 1.0 h 1.0", "not finite", "dropped"),
    ("ROBOTLASER1 0 -1.57 3.14 0.01 80 0.01 0 3 1 2", "truncated", "dropped"),
]


def _damaged(tmp_path: Path, body: str) -> Path:
    good = "FLASER 3 1 2 3 0 0 0 0 0 0 0.5 h 0.5"
    after = [f"FLASER 3 1 2 3 0 0 0 0 0 0 {k + 2.0} h {k + 2.0}" for k in range(19)]
    p = tmp_path / "bad.log"
    text = "\n".join([good, body, *after]) + "\n"
    p.write_bytes(text.encode("latin-1"))
    return p


@pytest.mark.parametrize(("body", "msg", "outcome"), MALFORMED)
def test_strict_refuses_malformed_lines_naming_file_and_line(
    tmp_path: Path, body: str, msg: str, outcome: str
) -> None:
    p = _damaged(tmp_path, body)
    with pytest.raises(LogFormatError, match=msg) as ei:
        read_carmen(p, strict=True)
    assert ei.value.line == 2
    assert str(ei.value).startswith(f"{p}:2:")


@pytest.mark.parametrize(("body", "msg", "outcome"), MALFORMED)
def test_lenient_reader_keeps_every_intact_scan(
    tmp_path: Path, body: str, msg: str, outcome: str
) -> None:
    d = read_carmen(_damaged(tmp_path, body))
    kept = {"dropped": 20, "invalid": 21, "repaired": 21}[outcome]
    assert len(d.scans) == kept


@pytest.mark.parametrize(("body", "msg", "outcome"), MALFORMED)
def test_lenient_reader_counts_what_it_did(
    tmp_path: Path, body: str, msg: str, outcome: str
) -> None:
    d = read_carmen(_damaged(tmp_path, body))
    got = {
        "dropped": [ln for ln, _ in d.info.dropped],
        "invalid": sum(d.info.invalid_readings.values()),
        "repaired": d.info.n_repaired_stamps,
    }[outcome]
    assert got == {"dropped": [2], "invalid": 1, "repaired": 1}[outcome]


def test_impossible_reading_becomes_an_invalid_beam(tmp_path: Path) -> None:
    d = read_carmen(_damaged(tmp_path, "FLASER 3 1 -0.01 3 0 0 0 0 0 0 1.0 h 1.0"))
    s = d.scans[1]
    assert (s.ranges[1], int(s.flags[1]), d.info.invalid_readings) == (
        np.inf,
        BEAM_INVALID,
        {"negative": 1},
    )


def test_bad_line_deep_in_a_big_group_is_located(tmp_path: Path) -> None:
    good = [f"FLASER 3 1 2 3 0 0 0 0 0 0 {k + 1.0} h {k + 1.0}" for k in range(500)]
    good[321] = "FLASER 3 1 2 3 0 0 0 0 0 0"  # truncated mid-line
    p = tmp_path / "deep.log"
    p.write_text("# header\n" + "\n".join(good) + "\n")
    with pytest.raises(LogFormatError) as ei:
        read_carmen(p, strict=True)
    assert ei.value.line == 323


def test_bad_line_deep_in_a_big_group_is_dropped_alone(tmp_path: Path) -> None:
    good = [f"FLASER 3 1 2 3 0 0 0 0 0 0 {k + 1.0} h {k + 1.0}" for k in range(500)]
    good[321] = "FLASER 3 1 2 3 0 0 0 0 0 0"  # truncated mid-line
    p = tmp_path / "deep.log"
    p.write_text("# header\n" + "\n".join(good) + "\n")
    d = read_carmen(p)
    assert [s.stamp for s in d.scans] == [k + 1.0 for k in range(500) if k != 321]


def test_only_the_first_ten_dropped_lines_are_listed(tmp_path: Path) -> None:
    lines = [f"FLASER 3 1 2 3 0 0 0 0 0 0 {k + 1.0} h {k + 1.0}" for k in range(40)]
    for k in range(0, 40, 3):
        lines[k] = lines[k][:20]  # 14 torn lines
    p = tmp_path / "torn.log"
    p.write_text("\n".join(lines) + "\n")
    info = read_carmen(p).info
    assert (info.n_dropped, [ln for ln, _ in info.dropped]) == (14, list(range(1, 30, 3)))


def test_unknown_types_skipped_and_counted(tmp_path: Path) -> None:
    p = tmp_path / "u.log"
    p.write_text(
        "# comment\nPARAM robot_x 1 h 0\nNEFF 12\nFOO bar baz\n\n"
        "FLASER 3 1 2 3 0 0 0 0 0 0 1.0 h 1.0\nTRUEPOS 0 0 0 0 0 0 1 h 1\n"
    )
    d = read_carmen(p)
    assert len(d.scans) == 1
    assert d.info.skipped == {"PARAM": 1, "NEFF": 1, "FOO": 1, "TRUEPOS": 1}


def test_empty_and_garbage_files(tmp_path: Path) -> None:
    p = tmp_path / "empty.log"
    p.write_text("# nothing\n")
    with pytest.raises(LogFormatError, match="no FLASER"):
        read_carmen(p)
    g = tmp_path / "g.log.gz"
    g.write_bytes(b"\x1f\x8b\x08\x00garbage")
    with pytest.raises(LogFormatError, match="gzip"):
        read_carmen(g)


def test_registry_detects_carmen_by_content(tmp_path: Path) -> None:
    p = tmp_path / "noext"
    write_carmen(p, _scans(3, 180), _odoms(4))
    assert detect_format(p) == "carmen"
    info = log_info(p)
    assert info.n_scans == 3 and info.beams == (180,)
    assert "3 × 180 beams" in info.summary()
    gz = tmp_path / "noext2"
    gz.write_bytes(gzip.compress(p.read_bytes()))
    assert detect_format(gz) == "carmen"
    with pytest.raises(LogFormatError, match="unknown log format"):
        junk = tmp_path / "junk.bin"
        junk.write_bytes(b"\x00\x01\x02")
        detect_format(junk)


# ----------------------------------------------------------------------------- real logs

RADISH = sorted((SHARED / "radish_corrected_logs").glob("*.log.gz")) if SHARED.is_dir() else []


def _check_clean(d: object) -> None:
    from icploc.logs import LogData

    assert isinstance(d, LogData)
    assert d.info.n_scans > 0
    st_ = np.array([s.stamp for s in d.scans])
    assert np.all(np.isfinite(st_)) and np.all(np.diff(st_) >= 0)
    ot = np.array([o.stamp for o in d.odometry])
    assert np.all(np.isfinite(ot)) and np.all(np.diff(ot) >= 0)
    for s in d.scans:
        assert not np.isnan(s.ranges).any()
        assert s.flags is not None
        assert np.array_equal(np.isinf(s.ranges), (s.flags & (BEAM_NO_RETURN | BEAM_INVALID)) != 0)
    assert np.all(np.isfinite(np.array([o.pose for o in d.odometry])))


@pytest.mark.shared_data
@needs_shared
@pytest.mark.parametrize("path", RADISH, ids=[p.name.split("-corrected")[0] for p in RADISH])
def test_real_radish_logs_parse_clean(path: Path) -> None:
    d = open_log(path)
    _check_clean(d)
    # no false damage on real logs: nothing dropped, no reading called impossible
    assert (d.info.n_dropped, d.info.invalid_readings) == (0, {})
    assert d.info.has_truth and d.truth_poses.shape == (d.info.n_scans, 3)
    assert d.info.beams[0] in (180, 181, 360, 361)
    assert d.info.skipped.get("NEFF", 0) == d.info.n_scans
    if path.name != "orebro-corrected.log.gz":
        assert any("repeat the preceding laser pose" in n for n in d.info.notes)


@pytest.mark.shared_data
@needs_shared
def test_real_radish_known_shapes_and_stamp_problems() -> None:
    base = SHARED / "radish_corrected_logs"
    intel = open_log(base / "intel-corrected.log.gz")
    assert (intel.info.n_scans, intel.info.beams) == (910, (180,))
    assert intel.info.stamps == "repaired" and "4 out-of-order scan" in intel.info.stamp_note
    csail = open_log(base / "csail-corrected.log.gz")
    assert (csail.info.n_scans, csail.info.beams, csail.info.stamps) == (406, (361,), "synthetic")
    orebro = open_log(base / "orebro-corrected.log.gz")
    assert orebro.info.stamps == "synthetic" and "zero" in orebro.info.stamp_note
    aces = open_log(base / "aces-corrected.log.gz")
    assert (aces.info.n_scans, aces.info.beams) == (440, (180,))


@pytest.mark.shared_data
@needs_shared
def test_real_laserazos() -> None:
    d = open_log(SHARED / "laserazosSM3" / "laserazosSM3.log")
    _check_clean(d)
    assert (d.info.n_scans, d.info.beams) == (778, (361,))
    assert d.info.stamps == "synthetic"  # the log has no stamps
    assert len(d.odometry) == 778 and d.odometry[0].extra["source"] == "FLASER"
    ang = d.scans[0].angles
    assert math.degrees(ang[0]) == pytest.approx(-90.0) and math.degrees(ang[-1]) == pytest.approx(
        90.0
    )
    n_invalid = sum(
        int(np.count_nonzero(s.flags & BEAM_INVALID)) for s in d.scans if s.flags is not None
    )
    assert n_invalid == 19234  # its NaN readings
    xy = np.array([o.pose[:2] for o in d.odometry])
    assert 50.0 < float(np.sum(np.hypot(*np.diff(xy, axis=0).T))) < 75.0  # "62 m"


@pytest.mark.shared_data
@needs_shared
def test_real_freiburg_course_csail_robotlaser1() -> None:
    d = open_log(SHARED / "freiburg_course" / "csail.log")
    _check_clean(d)
    assert (d.info.n_scans, d.info.beams) == (686, (361,))
    assert d.info.stamps == "ok"
    assert d.info.duration == pytest.approx(397.5, abs=0.5)
    assert d.scans[0].max_range == 80.0
    assert math.degrees(d.scans[0].angles[0]) == pytest.approx(-90.0, abs=1e-3)
    assert math.degrees(d.scans[0].angles[1] - d.scans[0].angles[0]) == pytest.approx(0.5, abs=1e-3)
    assert d.info.has_truth


def test_native_float_parser_hook(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """When the core provides parse_floats, the reader uses it (and still finds bad lines)."""
    from icploc import _core

    calls: list[int] = []

    def fake(text: str) -> np.ndarray:
        calls.append(len(text))
        return np.fromstring(text, dtype=np.float64, sep=" ")

    monkeypatch.setattr(_core, "parse_floats", fake, raising=False)
    scans = _scans(10, 361)
    p = tmp_path / "n.log"
    write_carmen(p, scans, _odoms(10))
    d = read_carmen(p)
    assert calls and len(d.scans) == 10
    assert np.array_equal(np.isinf(d.scans[3].ranges), np.isinf(scans[3].ranges))
    lines = p.read_text().splitlines()
    lines[5] = lines[5].replace(" ", " zz ", 1)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(LogFormatError) as ei:
        read_carmen(p, strict=True)
    assert ei.value.line == 6


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    cut=st.integers(0, 10_000),
    pos=st.integers(0, 10_000),
    junk=st.sampled_from(
        ["", "x", "nan", "-1", "1e400", " ", "\t\t", "3.5.5", "FLASER", "\n", "ODOM 1"]
    ),
)
def test_mutated_logs_parse_or_raise_log_format_error(
    tmp_path: Path, cut: int, pos: int, junk: str
) -> None:
    """Any damage to a log either still parses cleanly or gives a LogFormatError."""
    p = tmp_path / "m.log"
    write_carmen(p, _scans(4, 180), _odoms(6), precision=3)
    text = p.read_text()
    body = text[: min(cut, len(text))] if cut < len(text) else text
    k = pos % (len(body) + 1)
    p.write_text(body[:k] + junk + body[k:])
    try:
        d = read_carmen(p)
    except LogFormatError as e:
        assert str(p) in str(e)
        return
    for s in d.scans:
        assert not np.isnan(s.ranges).any() and len(s) > 0
    assert all(math.isfinite(o.stamp) and all(map(math.isfinite, o.pose)) for o in d.odometry)
