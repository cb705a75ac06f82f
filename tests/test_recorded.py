"""Raw-byte recording by the drivers and replay through the same parsers."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from icploc.drivers.powerbot import PowerBot
from icploc.drivers.recording import MAGIC, Recorder, RecordingFormatError, iter_records
from icploc.drivers.sick import PLS
from icploc.logs.recorded import is_recorded, read_recorded
from icploc.sim.device import Faults
from icploc.sim.powerbot_device import constant_plan
from icploc.sim.session import SimSession
from icploc.sim.world import World
from icploc.types import Odometry, Scan


def record_session(path: Path, faults: Faults | None = None) -> tuple[list[Scan], list[Odometry]]:
    world = World.box(10.0, 8.0)
    with SimSession(world, start_pose=(2.0, 4.0, 0.0), plan=constant_plan(0.5, 0.3), realtime=False,
                    laser_faults=faults) as sim:  # fmt: skip
        with Recorder(path) as rec:
            with (
                PLS(sim.laser_port, baud_settle=0.0, recorder=rec) as laser,
                PowerBot(sim.base_port, recorder=rec) as bot,
            ):
                scans = list(laser.scans(limit=40))
                odos = [s.to_odometry() for s in bot.sips(limit=60)]
    return scans, odos


def test_replay_reproduces_the_live_session(tmp_path: Path) -> None:
    path = tmp_path / "session.icpraw"
    live_scans, live_odos = record_session(
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
    for oa, ob in zip(live_odos, odos, strict=False):
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


def test_truncated_recording_is_tolerated_and_corrupt_one_rejected(tmp_path: Path) -> None:
    path = tmp_path / "s.icpraw"
    record_session(path)
    data = path.read_bytes()
    cut = tmp_path / "cut.icpraw"
    cut.write_bytes(data[: len(data) - 500])
    assert len(list(read_recorded(cut))) > 0
    bad = tmp_path / "bad.icpraw"
    hdr_len = struct.unpack("<I", data[8:12])[0]
    first = 12 + hdr_len
    bad.write_bytes(data[: first + 9] + b"\x07" + data[first + 10 :])  # record kind 7
    with pytest.raises(RecordingFormatError):
        list(read_recorded(bad))
    other = tmp_path / "x.log"
    other.write_text("FLASER 0 0 0\n")
    assert not is_recorded(other) and not is_recorded(tmp_path)
    with pytest.raises(RecordingFormatError):
        list(read_recorded(other))
    assert data.startswith(MAGIC)
