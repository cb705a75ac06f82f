"""Device engines without a transport: protocol behaviour and robustness to any input."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from icploc.drivers import arcos_protocol as ap
from icploc.drivers import sick_protocol as sp
from icploc.sim.pls_device import PLSDevice, ramp_source
from icploc.sim.powerbot_device import PowerBotDevice


def test_pls_engine_answers_per_spec() -> None:
    d = PLSDevice(source=ramp_source())
    d.receive(bytes.fromhex("0200020020253508"), 0.0)  # 20 25
    assert d.output(0.0, True) == bytes.fromhex(
        "06 02 80 03 00 A0 00 00 06 0A"
    )  # ACK + A0 00, status 00
    bad = bytearray(bytes.fromhex("0200020020253508"))
    bad[-1] ^= 1
    d.receive(bytes(bad), 0.0)
    assert d.output(0.0, True) == b"\x15"  # NAK on a bad CRC
    d.receive(sp.build_telegram(0x20, b"\x25", address=0x05), 0.0)
    assert d.output(0.0, True) == b""  # wrong address: silence
    d.receive(bytes.fromhex("0200020020405008"), 0.0)  # 20 40 outside installation mode
    assert d.output(0.0, True) == b"\x06" + sp.build_telegram(0x92, b"", address=0x80, status=0)
    d.receive(bytes.fromhex("02000A0020005349434B5F504C53CCFC"), 0.0)  # SICK_PLS
    d.receive(bytes.fromhex("0200020020405008"), 0.0)
    out = d.output(0.0, True)
    assert out.count(b"\x06") >= 2 and d.baudrate == 38400
    d.receive(bytes.fromhex("0200020030013118"), 0.0)  # 30 01
    out = d.output(0.0, True)
    assert out[0] == 0x06 and len(out) == 1 + 732 and sp.check_telegram(out[1:])


def test_powerbot_engine_handshake_bytes() -> None:
    d = PowerBotDevice()
    for n in (0, 1):
        d.receive(ap.encode_command(n), 0.0)
        assert d.output(0.0, True) == ap.encode_command(n)  # echoed verbatim
    d.receive(ap.encode_command(2), 0.0)
    assert d.output(0.0, True) == ap.build_sync2_reply("PowerBot", "Pioneer", "powerbot")
    assert d.connected and not d.sips_on
    d.receive(ap.encode_command(ap.OPEN), 0.0)
    sip = d.output(0.0, True)
    (pkt,) = ap.PacketParser().feed(sip)
    raw = ap.parse_sip(pkt.payload)
    assert raw.type == ap.SIP_STOPPED and raw.flags & 1 == 0  # motors start disabled


def test_powerbot_out_of_sequence_sync_restarts() -> None:
    d = PowerBotDevice()
    d.receive(ap.encode_command(0), 0.0)
    d.receive(ap.encode_command(2), 0.0)  # SYNC2 before SYNC1
    assert d.output(0.0, True) == ap.encode_command(0) and d.sync_state == 0


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=200), max_size=10))
def test_engines_survive_any_host_bytes(chunks: list[bytes]) -> None:
    pls = PLSDevice(source=ramp_source())
    bot = PowerBotDevice()
    for i, c in enumerate(chunks):
        for dev in (pls, bot):
            dev.receive(c, float(i))
            dev.output(float(i), True)
    assert pls.parser.buffered < sp.MAX_TELEGRAM and bot.parser.buffered <= ap.MAX_COUNT + 2
