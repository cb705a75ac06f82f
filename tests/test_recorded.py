"""Raw-byte recording by the drivers and replay through the same parsers."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from icploc.drivers.powerbot import PowerBot
from icploc.drivers.recording import (
    RECORD,
    Recorder,
    RecordingFormatError,
    iter_records,
    mounting_header,
    recorded_mounting,
)
from icploc.drivers.sick import PLS
from icploc.logs.recorded import is_recorded, read_recorded, replay_config
from icploc.messages import Odometry, Scan
from icploc.sim.device import Faults
from icploc.sim.powerbot_device import constant_plan
from icploc.sim.scenes import box
from icploc.sim.session import SimSession


def record_session(
    path: Path, faults: Faults | None = None, header: dict[str, object] | None = None
) -> tuple[list[Scan], list[Odometry], int]:
    """Record 40 scans and 60 SIPs; returns them and how many SIPs the driver's queue
    dropped (the SIP reader runs ahead while the test reads the scans first)."""
    world = box(10.0, 8.0)
    with SimSession(world, start_pose=(2.0, 4.0, 0.0), plan=constant_plan(0.5, 0.3), realtime=False,
                    laser_faults=faults) as sim:  # fmt: skip
        with Recorder(path, header=header) as rec:
            with (
                PLS(sim.laser_port, baud_settle=0.0, recorder=rec) as laser,
                PowerBot(sim.base_port, recorder=rec) as bot,
            ):
                scans = list(laser.scans(limit=40))
                odos = [s.to_odometry() for s in bot.sips(limit=60)]
                dropped = bot.stats["dropped_sips"]
    return scans, odos, dropped


def test_replay_reproduces_the_live_session(tmp_path: Path) -> None:
    path = tmp_path / "session.icpraw"
    live_scans, live_odos, dropped = record_session(
        path, Faults(corrupt_rate=0.05, garbage_rate=0.3, seed=4)
    )
    assert is_recorded(path)
    items = list(read_recorded(path))
    stamps = [i.stamp for i in items]
    assert stamps == sorted(stamps)
    scans = [i for i in items if isinstance(i, Scan)]
    odos = [i for i in items if isinstance(i, Odometry)]
    # the replay sees every byte the driver saw (and the scans / SIPs after the driver stopped reading)
    assert len(scans) >= len(live_scans) and len(odos) >= len(live_odos)
    for a, b in zip(live_scans, scans, strict=False):
        assert a.seq == b.seq and a.stamp == pytest.approx(b.stamp, abs=1e-9)
        np.testing.assert_array_equal(a.ranges, b.ranges)
        np.testing.assert_array_equal(a.angles, b.angles)
    # the SIPs the driver's full queue dropped before the test read them are in the replay
    for oa, ob in zip(live_odos, odos[dropped:], strict=False):
        assert oa.stamp == pytest.approx(ob.stamp, abs=1e-9)
        assert oa.pose == ob.pose and oa.velocity == ob.velocity


def test_recording_contents(tmp_path: Path) -> None:
    path = tmp_path / "s.icpraw"
    record_session(path)
    recs = list(iter_records(path))
    metas = [r.meta() for r in recs if r.kind == 0]
    assert {m.get("driver") for m in metas} >= {"sick", "powerbot"}
    assert any(m.get("baudrate") == 38400 for m in metas)  # the laser's baud switch is logged
    assert any(m.get("subtype") == "powerbot" for m in metas)
    assert any(
        r.kind == 2 and r.data == bytes.fromhex("0200020020243408") for r in recs
    )  # TX: start streaming


def _record_ends(data: bytes) -> list[int]:
    """Byte offsets where each record of a recording ends (walked from the header)."""
    hdr_len = struct.unpack("<I", data[8:12])[0]
    pos, ends = 12 + hdr_len, []
    while pos + RECORD.size <= len(data):
        n = RECORD.unpack(data[pos : pos + RECORD.size])[3]
        pos += RECORD.size + n
        if pos > len(data):
            break
        ends.append(pos)
    return ends


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("rec") / "s.icpraw"
    record_session(path)
    return path.read_bytes()


def test_truncated_recording_yields_every_complete_record(recording: bytes, tmp_path: Path) -> None:
    """Cut 500 bytes short (inside a record): exactly the records before the cut."""
    cut_at = len(recording) - 500
    ends = _record_ends(recording)
    complete = [e for e in ends if e <= cut_at]
    assert complete[-1] < cut_at  # the cut is inside a record, not at a boundary
    cut = tmp_path / "cut.icpraw"
    cut.write_bytes(recording[:cut_at])
    assert len(list(iter_records(cut))) == len(complete)


def test_truncated_recording_replays_like_the_clean_prefix(
    recording: bytes, tmp_path: Path
) -> None:
    """The decoded scans and odometry of a cut recording are those of the recording
    ending at the last complete record: the torn record is dropped, nothing else."""
    cut_at = len(recording) - 500
    clean_end = max(e for e in _record_ends(recording) if e <= cut_at)
    cut, clean = tmp_path / "cut.icpraw", tmp_path / "clean.icpraw"
    cut.write_bytes(recording[:cut_at])
    clean.write_bytes(recording[:clean_end])
    got = [(type(i).__name__, i.stamp) for i in read_recorded(cut)]
    want = [(type(i).__name__, i.stamp) for i in read_recorded(clean)]
    assert got == want and len(want) > 40


def test_corrupt_record_kind_is_rejected(recording: bytes, tmp_path: Path) -> None:
    bad = tmp_path / "bad.icpraw"
    hdr_len = struct.unpack("<I", recording[8:12])[0]
    first = 12 + hdr_len
    bad.write_bytes(recording[: first + 9] + b"\x07" + recording[first + 10 :])  # record kind 7
    with pytest.raises(RecordingFormatError, match="corrupt record header"):
        list(read_recorded(bad))


def test_other_files_are_not_recordings(tmp_path: Path) -> None:
    other = tmp_path / "x.log"
    other.write_text("FLASER 0 0 0\n")
    assert (is_recorded(other), is_recorded(tmp_path)) == (False, False)
    with pytest.raises(RecordingFormatError, match="bad magic"):
        list(read_recorded(other))


def test_recorder_flushes_every_record(tmp_path: Path) -> None:
    """A recording is complete on disk while it is still being written (a crash or
    Ctrl-C loses nothing that was recorded)."""
    path = tmp_path / "live.icpraw"
    with Recorder(path) as rec:
        dev = rec.device("x", {}, 1.0)
        rec.rx(dev, 2.0, b"abc")
        rec.tx(dev, 3.0, b"de")
        on_disk = [(r.kind, r.data) for r in iter_records(path)]
    assert on_disk == [(0, b'{"name": "x"}'), (1, b"abc"), (2, b"de")]


def test_recorder_write_error_stops_the_recording_not_the_caller(tmp_path: Path) -> None:
    """A write error (disk full) is kept in ``error``; the drivers calling rx/tx go on."""
    path = tmp_path / "full.icpraw"
    rec = Recorder(path)
    dev = rec.device("x", {}, 1.0)

    class Full:
        def write(self, b: bytes) -> int:
            raise OSError(28, "No space left on device")

        def close(self) -> None:
            pass

    assert rec._f is not None
    rec._f.close()
    rec._f = Full()  # type: ignore[assignment]
    rec.rx(dev, 2.0, b"abc")
    rec.rx(dev, 3.0, b"def")  # ignored, no exception
    assert (rec.closed, getattr(rec.error, "errno", None)) == (True, 28)


# -- the laser mounting in the recording ----------------------------------------------------

MOUNT = (0.251, 0.0, 0.0)  # the simulated PowerBot's laser, 0.251 m ahead of the centre


def test_a_run_records_its_laser_mounting(tmp_path: Path) -> None:
    from icploc.live import RunOutputs

    rec = tmp_path / "run.icpraw"
    outs = RunOutputs(None, rec, MOUNT)
    outs.commit()
    outs.close(None)
    assert recorded_mounting(rec) == MOUNT


def test_an_old_recording_has_no_mounting(tmp_path: Path) -> None:
    Recorder(tmp_path / "old.icpraw").close()
    assert recorded_mounting(tmp_path / "old.icpraw") is None


def test_a_malformed_mounting_is_an_error_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.icpraw"
    Recorder(path, header={"laser_mounting": [0.25, "x", 0]}).close()
    with pytest.raises(RecordingFormatError, match=r"bad\.icpraw.*laser_mounting"):
        recorded_mounting(path)


def test_replay_config_takes_the_recorded_mounting_without_a_config(tmp_path: Path) -> None:
    from icploc.config import LocalizerConfig

    path = tmp_path / "new.icpraw"
    Recorder(path, header=mounting_header(MOUNT)).close()
    cfg, note = replay_config(path, LocalizerConfig(), config_given=False)
    assert (cfg.scan.mounting, note.startswith("laser mounting from the recording")) == (MOUNT, True)


def test_replay_config_says_an_old_recording_has_no_mounting(tmp_path: Path) -> None:
    from icploc.config import LocalizerConfig

    path = tmp_path / "old.icpraw"
    Recorder(path).close()
    cfg, note = replay_config(path, LocalizerConfig(), config_given=False)
    assert (cfg.scan.mounting, "holds no laser mounting" in note) == ((0.0, 0.0, 0.0), True)


def test_replay_config_lets_a_config_with_another_mounting_win_and_says_so(tmp_path: Path) -> None:
    from icploc.config import LocalizerConfig

    path = tmp_path / "new.icpraw"
    Recorder(path, header=mounting_header(MOUNT)).close()
    given = LocalizerConfig().replace(scan={"laser_x": 0.3})
    cfg, note = replay_config(path, given, config_given=True)
    assert (cfg.scan.mounting, "from the config" in note, "+0.251" in note) == ((0.3, 0.0, 0.0), True, True)


@pytest.fixture(scope="module")
def box_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from icploc.maps import Map

    m = tmp_path_factory.mktemp("map") / "box.geojson"
    Map.from_lines(box(10.0, 8.0).lines).to_geojson(m)
    return m


def _first_pose_error(path: Path, box_map: Path) -> tuple[float, str]:
    """Replay without a config from the true start (2, 4, 0): the first estimate's
    distance from it (the robot has barely moved), and the summary."""
    from icploc.replay import replay

    res = replay(path, box_map, initial_pose=(2.0, 4.0, 0.0))
    p = res.poses[0]
    return float(np.hypot(p[0] - 2.0, p[1] - 4.0)), res.summary()


def test_replay_of_a_recording_with_its_mounting_needs_no_config(tmp_path: Path, box_map: Path) -> None:
    path = tmp_path / "new.icpraw"
    record_session(path, header=mounting_header(MOUNT))
    err, summary = _first_pose_error(path, box_map)
    assert (err < 0.05, "laser mounting from the recording" in summary) == (True, True)


def test_replay_of_an_old_recording_says_the_mounting_is_missing(tmp_path: Path, box_map: Path) -> None:
    path = tmp_path / "old.icpraw"
    record_session(path)
    err, summary = _first_pose_error(path, box_map)
    # the scans are taken at the centre: the fit is the laser's pose, 0.25 m ahead
    assert (err > 0.2, "holds no laser mounting" in summary) == (True, True)


def test_icploc_replay_of_a_new_recording_uses_its_mounting(tmp_path: Path, box_map: Path) -> None:
    from icploc.cli import app
    from typer.testing import CliRunner

    path = tmp_path / "new.icpraw"
    record_session(path, header=mounting_header(MOUNT))
    r = CliRunner().invoke(app, ["replay", str(path), "--map", str(box_map), "--initial-pose", "2,4,0",
                                 "--no-progress", "--max-lost", "1"])  # fmt: skip
    assert "log: laser mounting from the recording: x +0.251 m" in r.output, r.output
