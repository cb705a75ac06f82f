"""The log registry: format detection, the recorded-bytes path, merged iteration."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from icploc.logs import FORMATS, LogFormatError, detect_format, load_log, merge_in_time, open_log
from icploc.logs.carmen import flaser_angles, write_carmen
from icploc.logs.rosbag import write_rosbag
from icploc.messages import Odometry, Scan

HAVE_RECORDED = importlib.util.find_spec("icploc.logs.recorded") is not None


def _scan(t: float) -> Scan:
    return Scan(stamp=t, ranges=np.ones(180), angles=flaser_angles(180), max_range=8.0)


def test_formats_registered() -> None:
    assert {"carmen", "rosbag", "recorded"} <= set(FORMATS)


def test_detect_each_format(tmp_path: Path) -> None:
    c = tmp_path / "a.dat"
    write_carmen(c, [_scan(1.0)], [])
    b1 = tmp_path / "b.dat"
    write_rosbag(b1, [_scan(1.0)], [], version=1)
    b2 = tmp_path / "b2"
    write_rosbag(b2, [_scan(1.0)], [], version=2)
    assert detect_format(c) == "carmen"
    assert detect_format(b1) == "rosbag"
    assert detect_format(b2) == "rosbag"
    with pytest.raises(FileNotFoundError):
        detect_format(tmp_path / "missing.log")


def test_format_override_and_unknown(tmp_path: Path) -> None:
    c = tmp_path / "a.log"
    write_carmen(c, [_scan(1.0)], [])
    assert len(load_log(c, format="carmen").scans) == 1
    with pytest.raises(ValueError, match="unknown log format 'nope'"):
        load_log(c, format="nope")
    with pytest.raises(TypeError):
        open_log(c, no_such_option=1)


@settings(deadline=None)
@given(
    s=st.lists(st.floats(0, 100, allow_nan=False), max_size=20),
    o=st.lists(st.floats(0, 100, allow_nan=False), max_size=20),
)
def test_merge_in_time_is_sorted_and_stable(s: list[float], o: list[float]) -> None:
    scans = [_scan(t) for t in sorted(s)]
    odoms = [Odometry(stamp=t, pose=(0.0, 0.0, 0.0)) for t in sorted(o)]
    out = list(merge_in_time(scans, odoms))
    assert len(out) == len(s) + len(o)
    st_ = [m.stamp for m in out]
    assert st_ == sorted(st_)
    for a, b in zip(out, out[1:], strict=False):  # odometry first on ties
        if a.stamp == b.stamp:
            assert not (isinstance(a, Scan) and isinstance(b, Odometry))


@pytest.mark.skipif(not HAVE_RECORDED, reason="icploc.logs.recorded not written yet")
def test_recorded_sessions_are_detected_and_read(tmp_path: Path) -> None:
    from icploc.drivers import arcos_protocol as ap
    from icploc.drivers.recording import Recorder

    p = tmp_path / "session.bin"
    with Recorder(p) as rec:
        dev = rec.device("powerbot", {"driver": "powerbot", "subtype": "p3dx"}, 0.0)
        for k in range(5):
            raw = ap.RawSip(type=0x33, xpos=10 * k, ypos=0, thpos=0, lvel=0, rvel=0, battery=120,
                            stall_bumpers=0, control=0, flags=0, compass=0, sonar=(),
                            grip_state=0, anport=0, analog=0, digin=0, digout=0)  # fmt: skip
            rec.rx(dev, 1.0 + 0.1 * k, ap.build_sip(raw))
    assert detect_format(p) == "recorded"
    d = open_log(p)
    assert d.info.format == "recorded"
    assert d.info.n_scans == 0 and d.info.n_odometry == 5
    st_ = [m.stamp for m in d]
    assert st_ == sorted(st_)
    xs = [o.pose[0] for o in d.odometry]
    assert xs == sorted(xs) and xs[-1] > xs[0]


@pytest.mark.skipif(not HAVE_RECORDED, reason="icploc.logs.recorded not written yet")
def test_corrupt_recording_is_a_log_format_error(tmp_path: Path) -> None:
    from icploc.drivers.recording import MAGIC

    p = tmp_path / "bad.icpraw"
    p.write_bytes(MAGIC + b"\xff\xff\xff\x7f{")
    with pytest.raises(LogFormatError) as ei:
        open_log(p)
    assert str(p) in str(ei.value)


def test_truth_and_odometry_trajectories(tmp_path: Path) -> None:
    c = tmp_path / "t.log"
    poses = np.array([[1.0, 2.0, 0.5], [1.5, 2.0, 0.6]])
    odo = [Odometry(stamp=0.9 + 0.1 * k, pose=(0.1 * k, 0.0, 0.0)) for k in range(4)]
    write_carmen(c, [_scan(1.0), _scan(1.2)], odo, poses=poses)
    d = open_log(c)
    tr = d.truth()
    assert tr is not None and np.allclose(tr.poses, poses) and list(tr.stamps) == [1.0, 1.2]
    ot = d.odometry_trajectory()
    assert len(ot) == 4 and np.allclose(ot.xy[:, 0], [0.0, 0.1, 0.2, 0.3])
    b = tmp_path / "b.bag"
    write_rosbag(b, [_scan(1.0)], odo)
    assert open_log(b).truth() is None


def test_module_cli_prints_summaries(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from icploc.logs.__main__ import main

    c = tmp_path / "a.log"
    write_carmen(c, [_scan(1.0), _scan(2.0)], [])
    assert main([str(c)]) == 0
    out = capsys.readouterr().out
    assert "2 × 180 beams" in out and "[carmen]" in out
    bad = tmp_path / "bad.log"
    bad.write_text("FLASER 3 1 2\n")
    assert main([str(bad), str(tmp_path / "missing.log")]) == 1
    err = capsys.readouterr().err
    assert "bad.log: no FLASER" in err and "line 1: FLASER: truncated" in err
    assert "missing.log" in err
    assert main(["--strict", str(bad)]) == 1
    assert "bad.log:1: FLASER: truncated" in capsys.readouterr().err


def test_recorded_odometry_offset_re_anchors_a_power_cycled_base(tmp_path: Path) -> None:
    """The PowerBot driver re-anchors a controller that restarted its odometry at 0, 0, 0
    and records the offset as a META right after the SIP that revealed it: the replay
    applies it from that SIP on, so the odometry does not jump back to the origin."""
    from icploc.drivers import arcos_protocol as ap
    from icploc.drivers.recording import Recorder

    def sip(x_mm: int) -> bytes:
        return ap.build_sip(ap.RawSip(type=0x33, xpos=x_mm, ypos=0, thpos=0, lvel=0, rvel=0,
                                      battery=120, stall_bumpers=0, control=0, flags=0, compass=0,
                                      sonar=(), grip_state=0, anport=0, analog=0, digin=0,
                                      digout=0))  # fmt: skip

    p = tmp_path / "cycled.icpraw"
    with Recorder(p) as rec:
        dev = rec.device("powerbot", {"driver": "powerbot", "subtype": "p3dx"}, 0.0)
        for k in range(3):  # 0, 100, 200 mm
            rec.rx(dev, 1.0 + 0.1 * k, sip(100 * k))
        rec.rx(dev, 1.3, sip(0))  # power-cycled: the controller starts again at 0
        rec.flush()
        plain = [o.pose[0] for o in open_log(p).odometry]  # 0, d, 2d, then back to 0: a jump
        step = plain[1]
        # what the driver recorded: the last pose before the cycle
        rec.meta(dev, 1.3, {"odometry_offset": [plain[2], 0.0, 0.0]})
        rec.rx(dev, 1.4, sip(100))
    xs = [o.pose[0] for o in open_log(p).odometry]
    assert step > 0.0
    assert plain == pytest.approx([0.0, step, 2 * step, 0.0], abs=1e-9)
    assert xs == pytest.approx([0.0, step, 2 * step, 2 * step, 3 * step], abs=1e-9)


def test_readers_register_themselves_without_importing_rosbags() -> None:
    import subprocess
    import sys

    code = (
        "import sys, icploc.logs as L; names = list(L.FORMATS); "
        "print(names, any(m.split('.')[0] == 'rosbags' for m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['rosbag', 'carmen', 'recorded'] False"


def test_a_registered_reader_is_used_by_open_log(tmp_path: Path) -> None:
    from icploc.logs import LogData, LogInfo, register_format
    from icploc.logs._base import FORMATS as registry

    def load(path: str, **opts: object) -> LogData:
        return LogData(info=LogInfo(path=path, format="toy"), scans=[_scan(1.0)], odometry=[])

    p = tmp_path / "a.toy"
    p.write_text("toy log\n")
    register_format("toy", lambda path: path.endswith(".toy"), load, (".toy",), order=5)
    try:
        log = open_log(p)
    finally:
        del registry["toy"]
    assert (log.info.format, len(log.scans)) == ("toy", 1)
