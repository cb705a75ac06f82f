"""ROS 1 / ROS 2 bags: round trips through our writer, topic choice, REP 117 beams, the
index-less chunk reader, and the real (malformed-index) bag in ../shared/data."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from icploc.logs import LogFormatError, detect_format, open_log
from icploc.logs.rosbag import is_rosbag, iter_ros1_raw, read_rosbag, write_rosbag
from icploc.messages import BEAM_INVALID, BEAM_NO_RETURN, Odometry, Scan

SHARED = Path(__file__).parents[1] / ".." / "shared" / "data"
needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data not present")


def _data(n_scans: int = 8, beams: int = 181) -> tuple[list[Scan], list[Odometry]]:
    rng = np.random.default_rng(7)
    ang = np.linspace(-2.0, 2.0, beams)
    scans = []
    for k in range(n_scans):
        r = rng.uniform(0.1, 9.0, beams).astype(np.float32).astype(np.float64)
        r[rng.random(beams) < 0.1] = np.inf
        scans.append(
            Scan(stamp=1000.25 + 0.1 * k, ranges=r, angles=ang, max_range=10.0, min_range=0.05)
        )
    odoms = [
        Odometry(
            stamp=1000.2 + 0.05 * k, pose=(0.1 * k, 0.02 * k, wrap(0.4 * k)), velocity=(0.3, -0.2)
        )
        for k in range(2 * n_scans + 2)
    ]
    return scans, odoms


def wrap(a: float) -> float:
    return math.remainder(a, 2 * math.pi)


@pytest.mark.parametrize("version", [1, 2])
def test_round_trip(tmp_path: Path, version: int) -> None:
    scans, odoms = _data()
    p = tmp_path / ("x.bag" if version == 1 else "x")
    write_rosbag(p, scans, odoms, version=version)
    assert is_rosbag(p) and detect_format(p) == "rosbag"
    d = open_log(p)
    assert d.info.format == f"rosbag{version}"
    assert d.info.topics == {"/scan": "sensor_msgs/msg/LaserScan", "/odom": "nav_msgs/msg/Odometry"}
    assert len(d.scans) == len(scans) and len(d.odometry) == len(odoms)
    for a, b in zip(scans, d.scans, strict=True):
        assert b.stamp == pytest.approx(a.stamp, abs=1e-9)
        assert np.allclose(b.angles, a.angles, atol=1e-6)  # float32 angle fields
        assert np.array_equal(np.isinf(b.ranges), np.isinf(a.ranges))
        fin = np.isfinite(a.ranges)
        assert np.array_equal(b.ranges[fin], a.ranges[fin])
        assert b.flags is not None and np.array_equal((b.flags & BEAM_NO_RETURN) != 0, ~fin)
        assert b.max_range == pytest.approx(10.0) and b.frame == "laser"
    for oa, ob in zip(odoms, d.odometry, strict=True):
        assert ob.stamp == pytest.approx(oa.stamp, abs=1e-9)
        assert ob.pose == pytest.approx(oa.pose, abs=1e-9)
        assert ob.velocity == pytest.approx(oa.velocity)
    st = [m.stamp for m in d]
    assert st == sorted(st) and len(st) == len(scans) + len(odoms)


def test_rep117_beams(tmp_path: Path) -> None:
    r = np.array([0.01, np.nan, -np.inf, np.inf, 12.0, 3.0])  # < min, nan, -inf, +inf, > max, ok
    # our writer turns flagged beams into inf: write the raw values through rosbags directly
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    msg = T["sensor_msgs/msg/LaserScan"](
        header=T["std_msgs/msg/Header"](
            seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=5, nanosec=0), frame_id="l"
        ),
        angle_min=-1.0,
        angle_max=1.0,
        angle_increment=0.4,
        time_increment=0.0,
        scan_time=0.0,
        range_min=0.05,
        range_max=10.0,
        ranges=r.astype(np.float32),
        intensities=np.zeros(0, np.float32),
    )
    p2 = tmp_path / "raw.bag"
    with Writer(p2) as w:
        c = w.add_connection("/base_scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        w.write(c, 5_000_000_000, ts.serialize_ros1(msg, "sensor_msgs/msg/LaserScan"))
    d = read_rosbag(p2)
    sc = d.scans[0]
    assert sc.flags is not None
    assert list(sc.flags) == [
        BEAM_INVALID,
        BEAM_INVALID,
        BEAM_INVALID,
        BEAM_NO_RETURN,
        BEAM_NO_RETURN,
        0,
    ]
    assert np.isinf(sc.ranges[:5]).all() and sc.ranges[5] == pytest.approx(3.0)
    assert not np.isnan(sc.ranges).any()
    assert d.info.topics == {"/base_scan": "sensor_msgs/msg/LaserScan"}  # auto-detected


def test_topic_choice(tmp_path: Path) -> None:
    scans, odoms = _data(3)
    p = tmp_path / "t.bag"
    write_rosbag(p, scans, odoms, scan_topic="/front/scan", odom_topic="/wheel_odom")
    d = read_rosbag(p, scan_topic="/front/scan")
    assert len(d.scans) == 3 and len(d.odometry) == len(odoms)
    with pytest.raises(ValueError, match="not in bag"):
        read_rosbag(p, scan_topic="/nope")
    with pytest.raises(ValueError, match="expected sensor_msgs/msg/LaserScan"):
        read_rosbag(p, scan_topic="/wheel_odom")


def test_zero_header_stamps_use_bag_time(tmp_path: Path) -> None:
    scans, _ = _data(4)
    p = tmp_path / "z.bag"
    write_rosbag(p, [Scan(stamp=0.0, ranges=s.ranges, angles=s.angles) for s in scans], [])
    d = read_rosbag(p)
    # all header stamps 0 -> record time (also 0 here) -> unusable -> index stamps
    assert d.info.stamps == "synthetic"
    assert np.all(np.diff([s.stamp for s in d.scans]) > 0)


def test_raw_chunk_reader_matches_rosbags(tmp_path: Path) -> None:
    scans, odoms = _data(5)
    p = tmp_path / "c.bag"
    write_rosbag(p, scans, odoms)
    raw = list(iter_ros1_raw(p))
    assert len(raw) == len(scans) + len(odoms)
    assert {m[1] for m in raw} == {"sensor_msgs/msg/LaserScan", "nav_msgs/msg/Odometry"}
    assert [m[2] for m in raw] == sorted(m[2] for m in raw)


def _corrupt_index(p: Path) -> None:
    """Make the bag's index inconsistent the way the real demo bag is: a wrong data length
    in an index-data record. rosbags then refuses the file; the chunk scan must not."""
    b = bytearray(p.read_bytes())
    pos = b.find(b"op=\x04")
    assert pos > 0
    # walk back to the record start: header_len (4 bytes) precedes the header fields
    start = None
    for s in range(pos - 64, pos):
        (hl,) = struct.unpack_from("<I", b, s)
        if 0 < hl < 200 and s + 4 <= pos < s + 4 + hl:
            start = s
            break
    assert start is not None
    (hl,) = struct.unpack_from("<I", b, start)
    dl_at = start + 4 + hl
    (dl,) = struct.unpack_from("<I", b, dl_at)
    struct.pack_into("<I", b, dl_at, dl + 1000)
    p.write_bytes(bytes(b))


def test_inconsistent_index_read_by_chunks(tmp_path: Path) -> None:
    scans, odoms = _data(6)
    p = tmp_path / "bad_index.bag"
    write_rosbag(p, scans, odoms)
    _corrupt_index(p)
    from rosbags.highlevel import AnyReader

    with pytest.raises(Exception):  # noqa: B017, PT011 - whatever rosbags raises
        with AnyReader([p]) as r:
            list(r.messages())
    d = read_rosbag(p)
    assert len(d.scans) == 6 and len(d.odometry) == len(odoms)
    assert any("chunks read sequentially" in n for n in d.info.notes)


def test_truncated_bag_fails_clearly(tmp_path: Path) -> None:
    scans, odoms = _data(6)
    p = tmp_path / "trunc.bag"
    write_rosbag(p, scans, odoms)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(LogFormatError) as ei:
        read_rosbag(p)
    assert str(p) in str(ei.value)


def test_bag_without_scans_or_odometry(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    p = tmp_path / "s.bag"
    with Writer(p) as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        w.write(
            c,
            1,
            ts.serialize_ros1(ts.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"),
        )
    with pytest.raises(LogFormatError, match=r"no sensor_msgs/LaserScan.*/chatter"):
        read_rosbag(p)


@pytest.mark.shared_data
@needs_shared
def test_real_ros1_demo_bag() -> None:
    p = SHARED / "ros1_bag" / "laser_scan_matcher_demo.bag"
    d = open_log(p)
    assert d.info.format == "rosbag1"
    assert d.info.n_scans == 360 and d.info.beams == (681,) and d.info.n_odometry == 0
    assert any("AssertionError" in n for n in d.info.notes)
    assert d.info.duration == pytest.approx(35.8, abs=0.1)
    assert math.degrees(d.info.angle_min) == pytest.approx(-119.5, abs=0.1)
    assert math.degrees(d.info.angle_max) == pytest.approx(119.5, abs=0.1)
    st = np.array([s.stamp for s in d.scans])
    assert np.all(np.diff(st) > 0)
    for s in d.scans:
        assert not np.isnan(s.ranges).any()
        assert s.valid_mask().sum() > 100


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(1, 255)), min_size=1, max_size=4)
)
@example(flips=[(469492, 1)])  # a range turned into a signalling NaN (float32 -> 64 warned)
def test_damaged_ros1_bags_parse_or_raise_log_format_error(
    tmp_path: Path, flips: list[tuple[int, int]]
) -> None:
    scans, odoms = _data(3, beams=31)
    p = tmp_path / "f.bag"
    p.unlink(missing_ok=True)  # hypothesis reuses tmp_path across examples
    write_rosbag(p, scans, odoms)
    b = bytearray(p.read_bytes())
    for pos, x in flips:
        i = len(_MAGIC) + pos % (len(b) - len(_MAGIC))
        b[i] ^= x
    p.write_bytes(bytes(b))
    try:
        d = read_rosbag(p)
    except LogFormatError as e:
        assert str(p) in str(e)
        return
    for s in d.scans:
        assert not np.isnan(s.ranges).any()
        assert np.all(np.isfinite(s.angles))


_MAGIC = b"#ROSBAG V2.0\n"


@pytest.mark.parametrize("version", [1, 2])
def test_nan_odometry_message_is_dropped_and_counted(tmp_path: Path, version: int) -> None:
    scans, odoms = _data()
    odoms[5] = Odometry(stamp=odoms[5].stamp, pose=(math.nan, 0.0, 0.0))
    p = tmp_path / ("n.bag" if version == 1 else "n_bag2")
    write_rosbag(p, scans, odoms, version=version)
    d = read_rosbag(p)
    assert (len(d.scans), len(d.odometry), d.info.n_dropped) == (8, len(odoms) - 1, 1)


def test_nan_odometry_message_refused_when_strict(tmp_path: Path) -> None:
    scans, odoms = _data()
    odoms[5] = Odometry(stamp=odoms[5].stamp, pose=(math.nan, 0.0, 0.0))
    p = tmp_path / "n.bag"
    write_rosbag(p, scans, odoms)
    with pytest.raises(LogFormatError, match="non-finite pose"):
        read_rosbag(p, strict=True)
