"""ARCOS packet codec, SIP parsing and odometry unwrapping against PROTOCOLS.md §B.9,
the fixture file and hypothesis fuzzing."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from icploc.drivers import arcos_protocol as ap

FIX = json.loads(
    (Path(__file__).parent / "fixtures" / "protocols" / "arcos_fixtures.json").read_text()
)

SPEC_COMMANDS = [
    (0, None, "FA FB 03 00 00 00"),
    (1, None, "FA FB 03 01 00 01"),
    (2, None, "FA FB 03 02 00 02"),
    (4, 1, "FA FB 06 04 3B 01 00 05 3B"),
    (4, 0, "FA FB 06 04 3B 00 00 04 3B"),
    (5, 1000, "FA FB 06 05 3B E8 03 ED 3E"),
    (5, -1000, "FA FB 06 05 1B E8 03 ED 1E"),
    (1, 1, "FA FB 06 01 3B 01 00 02 3B"),
    (11, 300, "FA FB 06 0B 3B 2C 01 37 3C"),
    (11, -300, "FA FB 06 0B 1B 2C 01 37 1C"),
    (21, 20, "FA FB 06 15 3B 14 00 29 3B"),
    (21, -20, "FA FB 06 15 1B 14 00 29 1B"),
    (50, 2, "FA FB 06 32 3B 02 00 34 3B"),
    (55, None, "FA FB 03 37 00 37"),
    (3, "12345678", "FA FB 0D 03 2B 08 31 32 33 34 35 36 37 38 A7 C3"),
]


@pytest.mark.parametrize(("cmd", "arg", "hexstr"), SPEC_COMMANDS)
def test_spec_commands(cmd: int, arg: int | str | None, hexstr: str) -> None:
    raw = bytes.fromhex(hexstr)
    assert ap.encode_command(cmd, arg) == raw
    (pkt,) = ap.PacketParser().feed(raw)
    c = ap.decode_command(pkt.payload)
    assert c.cmd == cmd
    assert c.arg == (arg.encode() if isinstance(arg, str) else arg)


def test_fixtures() -> None:
    assert ap.encode_command(ap.SYNC0).hex() == FIX["sync0"]
    assert ap.encode_command(ap.SYNC1).hex() == FIX["sync1"]
    assert ap.encode_command(ap.SYNC2).hex() == FIX["sync2"]
    assert ap.encode_command(ap.ENABLE, 1).hex() == FIX["enable1"]
    assert ap.encode_command(ap.VEL, -300).hex() == FIX["vel_m300"]
    assert ap.encode_command(ap.RVEL, 20).hex() == FIX["rvel_p20"]
    reply = bytes.fromhex(FIX["sync2_reply_example"])
    assert ap.build_sync2_reply("PowerBot", "Pioneer", "powerbot") == reply
    (pkt,) = ap.PacketParser().feed(reply)
    assert ap.parse_sync2(pkt.payload) == ("PowerBot", "Pioneer", "powerbot")


def test_fixture_sip_decodes_to_spec_values() -> None:
    raw = bytes.fromhex(FIX["sip_example"])
    (pkt,) = ap.PacketParser().feed(raw, 5.0)
    sip = ap.parse_sip(pkt.payload)
    assert (sip.xpos, sip.ypos, sip.thpos, sip.lvel, sip.rvel) == (1000, 200, 1024, 100, 120)
    assert sip.battery == 245 and sip.flags & 1 and sip.sonar == ((0, 1500), (1, 2000))
    assert ap.build_sip(sip) == raw
    dec = ap.SipDecoder(ap.POWERBOT).decode(pkt)
    assert dec is not None
    assert dec.pose[0] == pytest.approx(1000 * 0.5813 / 1000) and dec.pose[1] == pytest.approx(
        200 * 0.5813 / 1000
    )
    assert dec.pose[2] == pytest.approx(1024 * 0.001534)  # ~ +90 degrees
    assert dec.left_velocity == pytest.approx(0.1) and dec.right_velocity == pytest.approx(0.12)
    assert dec.w == pytest.approx(10 * 0.00373)  # (R - L) / 2 * DiffConvFactor
    assert dec.battery_volts == pytest.approx(24.5) and dec.motors_enabled and not dec.stall
    assert dec.sonar == {0: 1.5, 1: 2.0} and dec.stamp == 5.0
    odo = dec.to_odometry()
    assert odo.pose == dec.pose and odo.velocity == (dec.v, dec.w)


def test_params_by_subtype() -> None:
    assert ap.params_for("powerbot").dist_conv == 0.5813
    assert ap.params_for("PowerBot-SH").dist_conv == 1.0
    assert ap.params_for("p3dx-sh").dist_conv == 1.0
    assert ap.params_for("powerbot").angle_conv == 0.001534


def test_vel2_negative_left_is_sent_as_magnitude_and_rebuilt() -> None:
    arg = ap.vel2_argument(-200.0, 300.0)
    pkt = ap.encode_command(ap.VEL2, arg)
    assert pkt[4] == ap.ARG_NINT  # negative: 0x1B + magnitude (§B.4)
    (p,) = ap.PacketParser().feed(pkt)
    c = ap.decode_command(p.payload)
    assert isinstance(c.arg, int)
    assert ap.decode_vel2(c.arg) == (-200.0, 300.0)


@pytest.mark.parametrize("left", [-2540, -20, 0, 40, 2540])
@pytest.mark.parametrize("right", [-2560, -60, 0, 20, 2540])
def test_vel2_roundtrip(left: int, right: int) -> None:
    c = ap.decode_command(ap.encode_command(ap.VEL2, ap.vel2_argument(left, right))[3:-2])
    assert isinstance(c.arg, int)
    assert ap.decode_vel2(c.arg) == (left, right)


def test_parser_resync_and_errors() -> None:
    good = ap.encode_command(ap.VEL, 300)
    bad = bytearray(good)
    bad[-1] ^= 0xFF
    p = ap.PacketParser()
    out = p.feed(b"\xfa\xfa\xfb\x01" + bytes(bad) + b"\x00\xfa" + good + b"\xfa\xfb\xff")
    assert [o.payload for o in out] == [good[3:-2]]
    assert p.stats.checksum_errors == 1 and p.stats.length_errors == 2  # COUNT 1 and COUNT 255


def _unwrap_series(xs: list[int], ths: list[int] | None = None) -> list[tuple[float, float, float]]:
    u = ap.OdometryUnwrapper(ap.POWERBOT)
    ths = ths or [0] * len(xs)
    return [u.update(x & 0x7FFF, 0, t) for x, t in zip(xs, ths, strict=True)]


def test_unwrap_forward_across_15_bit_wrap() -> None:
    xs = list(range(32000, 33600, 100))  # raw counter wraps at 32768
    poses = _unwrap_series(xs)
    x = [p[0] for p in poses]
    assert all(b - a == pytest.approx(100 * 0.5813 / 1000) for a, b in zip(x, x[1:], strict=False))
    assert x[-1] - x[0] == pytest.approx(1500 * 0.5813 / 1000)


def test_unwrap_backward_across_zero() -> None:
    xs = list(range(500, -1500, -100))  # goes below 0 -> 32768 - k
    poses = _unwrap_series(xs)
    x = [p[0] for p in poses]
    assert x[0] == pytest.approx(500 * 0.5813 / 1000)
    assert x[-1] == pytest.approx(-1400 * 0.5813 / 1000)
    assert all(b < a for a, b in zip(x, x[1:], strict=False))


def test_unwrap_heading_across_pi() -> None:
    ths = [2000, 2040, -2048, -2000, -1900]
    poses = _unwrap_series([0] * len(ths), ths)
    assert poses[1][2] == pytest.approx(2040 * 0.001534)
    assert abs(poses[2][2]) == pytest.approx(math.pi, abs=0.01)
    assert poses[4][2] == pytest.approx(-1900 * 0.001534, abs=1e-3)


def test_decode_command_errors() -> None:
    with pytest.raises(ap.ArcosProtocolError):
        ap.decode_command(b"\x0b\x3b\x01")
    with pytest.raises(ap.ArcosProtocolError):
        ap.decode_command(b"\x0b\x99\x01\x00")
    with pytest.raises(ap.ArcosProtocolError):
        ap.parse_sip(b"\x32" + bytes(10))
    with pytest.raises(ap.ArcosProtocolError):
        ap.encode_command(ap.VEL, 70000)


sip_strategy = st.builds(
    ap.RawSip,
    type=st.sampled_from([0x32, 0x33]),
    xpos=st.integers(0, 0x7FFF), ypos=st.integers(0, 0x7FFF), thpos=st.integers(-2048, 2047),
    lvel=st.integers(-2000, 2000), rvel=st.integers(-2000, 2000), battery=st.integers(0, 255),
    stall_bumpers=st.integers(0, 0xFFFF), control=st.integers(-32768, 32767), flags=st.integers(0, 0xFFFF),
    compass=st.integers(0, 255),
    sonar=st.lists(st.tuples(st.integers(0, 31), st.integers(0, 0xFFFF)), max_size=16).map(tuple),
    grip_state=st.integers(0, 255), anport=st.integers(0, 255), analog=st.integers(0, 255),
    digin=st.integers(0, 255), digout=st.integers(0, 255),
    battery_x10=st.one_of(st.none(), st.integers(-32768, 32767)),
)  # fmt: skip


@settings(max_examples=200, deadline=None)
@given(sip_strategy)
def test_sip_roundtrip(sip: ap.RawSip) -> None:
    (pkt,) = ap.PacketParser().feed(ap.build_sip(sip))
    assert ap.parse_sip(pkt.payload) == sip


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=300), max_size=12))
def test_fuzz_parser_never_raises_and_stays_bounded(chunks: list[bytes]) -> None:
    p = ap.PacketParser()
    dec = ap.SipDecoder()
    for c in chunks:
        for pkt in p.feed(c):
            assert ap.checksum(pkt.payload) is not None
            dec.decode(pkt)  # never raises: bad SIPs are counted
            try:
                ap.decode_command(pkt.payload)
            except ap.ArcosProtocolError:
                pass
        assert p.buffered <= ap.MAX_COUNT + 2


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=300), sip_strategy)
def test_fuzz_sip_after_noise_is_found(noise: bytes, sip: ap.RawSip) -> None:
    frame = ap.build_sip(sip)
    p = ap.PacketParser()
    out = p.feed(noise + frame) + p.feed(frame)
    assert any(o.payload == frame[3:-2] for o in out)


@settings(max_examples=200, deadline=None)
@given(st.integers(-(10**6), 10**6), st.lists(st.integers(-4000, 4000), max_size=60))
def test_unwrap_matches_integrated_counter(start: int, steps: list[int]) -> None:
    u = ap.OdometryUnwrapper(ap.POWERBOT_SH)
    true = start
    u.update(true & 0x7FFF, 0, 0)
    base = u.x_units
    for s in steps:
        true += s
        u.update(true & 0x7FFF, 0, 0)
    assert u.x_units - base == true - start
