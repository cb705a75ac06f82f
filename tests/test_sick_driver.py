"""SICK driver against the PLS / LMS device simulator over a real pseudo-terminal."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import numpy as np
import pytest
import serial
from icploc.drivers import sick_protocol as sp
from icploc.drivers.sick import PLS, LMS2xx, SickError, SickRefused, SickTimeout
from icploc.sim.device import DeviceRunner, Faults
from icploc.sim.pls_device import PLSDevice


def index_source(dev_holder: list[PLSDevice]) -> object:
    """Scan k carries k in every beam: ranges = 1 m + k cm + beam mm-ish ramp."""

    def src(t: float) -> np.ndarray:
        k = dev_holder[0].scan_index
        return 1.0 + 0.01 * (k % 2000) + 0.01 * (np.arange(361) % 50)

    return src


def make_device(variant: str = "pls", faults: Faults | None = None, **kw: object) -> PLSDevice:
    holder: list[PLSDevice] = []
    dev = PLSDevice(source=index_source(holder), variant=variant, faults=faults or Faults(), **kw)  # type: ignore[arg-type]
    holder.append(dev)
    return dev


@pytest.fixture
def sim() -> Iterator[DeviceRunner]:
    run = DeviceRunner(make_device()).start()
    yield run
    run.stop()
    assert run.error is None


def scan_index(scan: object) -> int:
    r = scan.ranges  # type: ignore[attr-defined]
    return int(round((r[0] - 1.0) * 100))


def test_connect_configure_stream_1000_and_close(sim: DeviceRunner) -> None:
    dev = sim.engine
    assert isinstance(dev, PLSDevice)
    with PLS(sim.port, baudrate=38400, baud_settle=0.0) as laser:
        assert laser.ser is not None
        assert laser.ser.parity == serial.PARITY_EVEN and laser.ser.baudrate == 38400
        assert dev.baudrate == 38400 and dev.streaming
        sent = [(t.cmd, t.data) for t in dev.host_telegrams]
        assert sent == [
            (0x20, b"\x25"),  # probe at 9600
            (0x20, b"\x00SICK_PLS"),  # installation mode before the baud change (PLS)
            (0x20, b"\x40"),  # 38400
            (0x20, b"\x25"),  # re-probe at 38400
            (0x20, b"\x24"),  # stream all values
        ]
        scans = list(laser.scans(limit=1000))
        assert sim.transport.host_settings().baudrate == 38400  # type: ignore[attr-defined]
    assert not dev.streaming
    assert (dev.host_telegrams[-1].cmd, dev.host_telegrams[-1].data) == (0x20, b"\x25")
    assert [s.seq for s in scans] == list(range(1, 1001))
    idx = [scan_index(s) for s in scans]
    assert idx == list(range(idx[0], idx[0] + 1000))
    for s in scans[:50]:
        k = scan_index(s)
        np.testing.assert_allclose(
            s.ranges, 1.0 + 0.01 * k + 0.01 * (np.arange(361) % 50), atol=1e-9
        )
        assert s.angles[0] == pytest.approx(-math.pi / 2) and s.angles[-1] == pytest.approx(
            math.pi / 2
        )
    stamps = np.array([s.stamp for s in scans])
    assert (np.diff(stamps) >= 0).all()
    assert laser.stats["parser_crc_errors"] == 0 and laser.ser is None


def test_corrupted_telegrams_and_garbage(sim: DeviceRunner) -> None:
    dev = sim.engine
    assert isinstance(dev, PLSDevice)
    with PLS(sim.port, baud_settle=0.0) as laser:
        dev.faults.corrupt_rate = 0.05
        dev.faults.garbage_rate = 0.5
        dev.faults.garbage_max = 60
        scans = list(laser.scans(limit=600))
        stats = laser.stats
    by_index = {r.index: r for r in dev.b0_log}
    got = [scan_index(s) for s in scans]
    first, last = got[0], got[-1]
    intact = [k for k in range(first, last + 1) if by_index[k].intact]
    corrupted = [k for k in range(first, last + 1) if not by_index[k].intact]
    assert len(corrupted) > 10  # the faults really happened
    assert got == intact  # every intact telegram decoded, in order, no corrupted one
    for s in scans:
        (tel,) = [
            e
            for e in sp.TelegramParser().feed(by_index[scan_index(s)].frame)
            if isinstance(e, sp.Telegram)
        ]
        np.testing.assert_array_equal(s.ranges, sp.decode_scan(tel).ranges)
    # (a flipped STX / address byte shows up as dropped bytes, not as a CRC error)
    assert stats["parser_crc_errors"] >= len(corrupted) // 2 and stats["parser_dropped_bytes"] > 0


def test_dropped_bytes_never_yield_a_scan(sim: DeviceRunner) -> None:
    dev = sim.engine
    assert isinstance(dev, PLSDevice)
    with PLS(sim.port, baud_settle=0.0) as laser:
        dev.faults.drop_rate = 0.1
        scans = list(laser.scans(limit=200))
    by_index = {r.index: r for r in dev.b0_log}
    got = [scan_index(s) for s in scans]
    assert all(by_index[k].intact for k in got)
    assert got == [k for k in range(got[0], got[-1] + 1) if by_index[k].intact]


def test_nak_storm_is_ridden_out_with_backoff() -> None:
    run = DeviceRunner(make_device(faults=Faults(nak_storm=3))).start()
    try:
        t0 = time.monotonic()
        with PLS(run.port, baud_settle=0.0) as laser:
            # probe: NAK, 30 ms, NAK -> NAKs prove a device at 9600 -> full retries: NAK, 30 ms, ok
            assert laser.stats["naks"] == 3 and laser.stats["retries"] == 2
            assert laser.current_baud == 38400
            assert time.monotonic() - t0 >= 2 * 0.03
            assert len(list(laser.scans(limit=5))) == 5
    finally:
        run.stop()


def test_endless_nak_storm_gives_up() -> None:
    run = DeviceRunner(make_device(faults=Faults(nak_storm=1000))).start()
    try:
        with pytest.raises(SickTimeout):
            PLS(run.port, connect_baudrates=(9600,), retries=2, backoff=0.01).open()
    finally:
        run.stop()


def test_late_replies_within_timeout() -> None:
    run = DeviceRunner(make_device(faults=Faults(late_reply=0.2))).start()
    try:
        t0 = time.monotonic()
        # every reply 0.2 s late, waited for up to 2 s: a margin a loaded machine keeps
        with PLS(run.port, baud_settle=0.0, ack_timeout=2.0) as laser:
            assert time.monotonic() - t0 >= 5 * 0.2
            assert laser.stats["timeouts"] == 0
            assert len(list(laser.scans(limit=3))) == 3
    finally:
        run.stop()


def test_missed_requests_are_retried() -> None:
    run = DeviceRunner(make_device(faults=Faults(ignore_rate=0.5, seed=3))).start()
    try:
        # a missed request is answered never, a heard one within ~15 ms: 0.5 s tells them
        # apart on a loaded machine too (and the seeded misses stay the same sequence)
        with PLS(run.port, baud_settle=0.0, ack_timeout=0.5, retries=10) as laser:
            assert laser.stats["timeouts"] >= 1
            assert len(list(laser.scans(limit=3))) == 3
    finally:
        run.stop()


def test_vanished_device_stalls_with_timeout(sim: DeviceRunner) -> None:
    dev = sim.engine
    assert isinstance(dev, PLSDevice)
    laser = PLS(sim.port, baud_settle=0.0, stall_timeout=1.5, retries=0, ack_timeout=0.5)
    laser.open()
    try:
        assert len(list(laser.scans(limit=5))) == 5
        dev.vanish()
        with pytest.raises(SickTimeout):
            for _ in laser.scans(limit=10**6):
                pass
    finally:
        laser.close()  # must not hang or raise although the device is gone


def _scans_after(laser: PLS, seq: int, n: int) -> list:  # type: ignore[type-arg]
    """The next ``n`` scans numbered after ``seq`` (older ones still queued are skipped)."""
    out = []
    t0 = time.monotonic()
    while len(out) < n and time.monotonic() - t0 < 60.0:
        s = laser.get(timeout=1.0)
        if s is not None and s.seq > seq:
            out.append(s)
    return out


def test_disconnect_and_reconnect_after_power_cycle(sim: DeviceRunner) -> None:
    """The scanner goes silent; once the driver noticed the stall and is reconnecting, it
    comes back power-cycled (9600 Bd, idle): the driver finds it, switches it to 38400
    and streams again. Event-driven, no fixed delays."""
    dev = sim.engine
    assert isinstance(dev, PLSDevice)
    with PLS(sim.port, baud_settle=0.0, stall_timeout=1.0, auto_reconnect=True, ack_timeout=0.5,
             reconnect_backoff=0.05, connect_baudrates=(9600, 38400)) as laser:  # fmt: skip
        laser.start()
        assert len([laser.get(timeout=5.0) for _ in range(10)]) == 10
        dev.vanish()
        t0 = time.monotonic()
        while not laser.stats["reconnects"] and time.monotonic() - t0 < 60.0:
            laser.get(timeout=0.1)  # drain what was buffered before the device went quiet
        seq_then = laser.seq
        dev.revive()
        after = _scans_after(laser, seq_then, 10)
        assert laser.stats["reconnects"] == 1
        assert dev.baudrate == 38400 and dev.streaming
        assert all(len(s) == 361 for s in after)


def test_unplugged_adapter_is_reconnected(tmp_path: object) -> None:
    """The USB adapter is pulled (reads fail, the device node disappears) and plugged
    back: the driver retries with back-off until the node is there and streams again."""
    run = DeviceRunner(make_device(), unpluggable=True).start()
    try:
        with PLS(run.port, baud_settle=0.0, auto_reconnect=True, ack_timeout=0.5,
                 reconnect_backoff=0.05, connect_baudrates=(9600, 38400)) as laser:  # fmt: skip
            laser.start()
            assert laser.get(timeout=5.0) is not None
            run.unplug()
            t0 = time.monotonic()
            while laser.link_up and time.monotonic() - t0 < 60.0:
                laser.get(timeout=0.1)
            seq_then = laser.seq  # scans up to here were read before the unplug
            run.replug(power_cycle=True)
            after = _scans_after(laser, seq_then, 5)
            assert laser.stats["reconnects"] == 1 and laser.link_up
            assert [s.seq for s in after] == list(range(seq_then + 1, seq_then + 6))
    finally:
        run.stop()


def test_laser_that_never_comes_back_raises_a_clear_timeout() -> None:
    run = DeviceRunner(make_device(), unpluggable=True).start()
    try:
        with PLS(run.port, baud_settle=0.0, auto_reconnect=True, ack_timeout=0.2,
                 reconnect_timeout=1.0, connect_baudrates=(9600, 38400)) as laser:  # fmt: skip
            laser.start()
            assert laser.get(timeout=5.0) is not None
            run.unplug()
            with pytest.raises(SickTimeout, match="did not come back within 1 s"):
                for _ in range(10**5):
                    laser.get(timeout=0.5)
    finally:
        run.stop()


def test_close_and_reopen_same_port(sim: DeviceRunner) -> None:
    dev = sim.engine
    assert isinstance(dev, PLSDevice)
    with PLS(sim.port, baud_settle=0.0) as laser:
        assert len(list(laser.scans(limit=5))) == 5
    assert not dev.streaming and dev.baudrate == 38400
    with PLS(sim.port, baud_settle=0.0) as laser:  # finds the device at 38400 this time
        assert laser.current_baud == 38400
        assert len(list(laser.scans(limit=5))) == 5


def test_background_thread_queue_and_callback(sim: DeviceRunner) -> None:
    seen: list[int] = []
    # a queue deep enough that a consumer slowed by a loaded machine drops nothing
    with PLS(sim.port, baud_settle=0.0, queue_size=2000) as laser:
        laser.start(callback=lambda s: seen.append(s.seq))
        got = list(laser.scans(limit=100))
        assert laser.get(timeout=2.0) is not None
    # scans decoded while configuring were queued before the callback existed
    assert [s.seq for s in got] == list(range(got[0].seq, got[0].seq + 100))
    assert seen == list(range(seen[0], seen[0] + len(seen))) and len(seen) >= 90
    assert seen[0] <= got[10].seq


def test_poll_mode(sim: DeviceRunner) -> None:
    dev = sim.engine
    assert isinstance(dev, PLSDevice)
    with PLS(sim.port, baud_settle=0.0, mode="poll") as laser:
        scans = list(laser.scans(limit=20))
        assert not dev.streaming
    assert len(scans) == 20
    assert sum(1 for t in dev.host_telegrams if t.cmd == 0x30) == 20


def test_pls_refuses_baud_change_outside_installation_mode(sim: DeviceRunner) -> None:
    with PLS(sim.port, baudrate=9600, mode="poll") as laser:
        with pytest.raises(SickRefused):
            laser.transact(0x20, b"\x40")


def test_wrong_password_is_reported() -> None:
    run = DeviceRunner(make_device()).start()
    try:
        laser = PLS(run.port, baud_settle=0.0)
        laser.password = b"SICK_XXX"
        with pytest.raises(SickRefused, match="wrong password"):
            laser.open()
    finally:
        run.stop()


def test_wrong_host_baud_gets_no_answer(sim: DeviceRunner) -> None:
    # the device is at 9600; a host at 19200 only produces line noise on both sides
    with pytest.raises(SickTimeout):
        PLS(sim.port, connect_baudrates=(19200,), retries=1, ack_timeout=0.05).open()
    assert sim.line_mismatch_bytes > 0


def test_hangup_raises_sick_error() -> None:
    run = DeviceRunner(make_device()).start()
    laser = PLS(run.port, baud_settle=0.0)
    laser.open()
    try:
        assert len(list(laser.scans(limit=3))) == 3
        run.stop(close=True)  # the device side of the pty disappears
        with pytest.raises(SickError):
            for _ in laser.scans(limit=10**6):
                pass
    finally:
        laser.close()


def test_lms_variant_direct_baud_change_and_100deg_field() -> None:
    run = DeviceRunner(make_lms()).start()
    try:
        with LMS2xx(
            run.port, baudrate=19200, fov_deg=100, resolution_deg=0.5, baud_settle=0.0
        ) as laser:
            assert laser.ser is not None and laser.ser.parity == serial.PARITY_NONE
            assert laser.device_type == "LMS200;301063;V02.10"
            sent = [(t.cmd, t.data[:1]) for t in run.engine.host_telegrams]  # type: ignore[attr-defined]
            assert (0x20, b"\x00") not in sent  # no installation mode needed on the LMS
            s = next(laser.scans())
        assert len(s) == 201
        assert s.angles[0] == pytest.approx(-math.radians(50)) and s.angles[-1] == pytest.approx(
            math.radians(50)
        )
        np.testing.assert_allclose(s.ranges[np.isfinite(s.ranges)], 3.0)
    finally:
        run.stop()


def make_lms() -> PLSDevice:
    return PLSDevice(source=lambda t: np.full(201, 3.0), variant="lms", max_range=8.0)


class _BufferedLine:
    """A serial line (the part of pyserial the driver reads) holding bytes that arrived."""

    def __init__(self, data: bytes) -> None:
        self.data = data

    @property
    def in_waiting(self) -> int:
        return len(self.data)

    def read(self, n: int = 1) -> bytes:
        out, self.data = self.data[:n], self.data[n:]
        return out


def test_an_ack_that_came_while_the_driver_slept_past_its_deadline_counts() -> None:
    """A starved thread wakes after its ACK deadline: the ACK that arrived meanwhile is
    read, not taken for a timeout (which cost a retry per late wake-up)."""
    from icploc import clock

    laser = PLS("unused")
    laser.ser = _BufferedLine(bytes([sp.ACK]))  # type: ignore[assignment]
    ev = laser._next_control(clock.now() - 1.0)
    assert isinstance(ev, sp.ByteEvent) and ev.value == sp.ACK
