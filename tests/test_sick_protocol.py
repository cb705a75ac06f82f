"""SICK telegram codec and stream parser against the spec's byte examples (PROTOCOLS.md
§A.9), the fixture files, and hypothesis fuzzing."""

from __future__ import annotations

import json
import math
import random
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from icploc.drivers import sick_protocol as sp
from icploc.messages import BEAM_DAZZLE, BEAM_FIELD_A, BEAM_FIELD_B, BEAM_INVALID, BEAM_NO_RETURN

FIX = json.loads(
    (Path(__file__).parent / "fixtures" / "protocols" / "sick_fixtures.json").read_text()
)

# (cmd, data, address, status, expected hex) from the table in §A.9
SPEC_TELEGRAMS = [
    (0x20, b"\x24", 0x00, None, "02 00 02 00 20 24 34 08"),
    (0x20, b"\x25", 0x00, None, "02 00 02 00 20 25 35 08"),
    (0x30, b"\x01", 0x00, None, "02 00 02 00 30 01 31 18"),
    (0xA0, b"\x00", 0x80, 0x10, "02 80 03 00 A0 00 10 16 0A"),
    (0x31, b"", 0x00, None, "02 00 01 00 31 15 12"),
    (0x20, b"\x00SICK_LMS", 0x00, None, "02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 BE C5"),
    (0x20, b"\x00SICK_PLS", 0x00, None, "02 00 0A 00 20 00 53 49 43 4B 5F 50 4C 53 CC FC"),
    (0x20, b"\x40", 0x00, None, "02 00 02 00 20 40 50 08"),
    (0x20, b"\x42", 0x00, None, "02 00 02 00 20 42 52 08"),
    (0x20, b"\x41", 0x00, None, "02 00 02 00 20 41 51 08"),
    (0x20, b"\x48", 0x00, None, "02 00 02 00 20 48 58 08"),
    (0x10, b"", 0x00, None, "02 00 01 00 10 34 12"),
    (0x91, b"", 0x80, 0x10, "02 80 02 00 91 10 79 30"),
    (0x92, b"", 0x80, 0x10, "02 80 02 00 92 10 7F 33"),
    (0x3A, b"", 0x00, None, "02 00 01 00 3A 1E 12"),
    (0xBA, b"LMS200;301063;V02.10 ", 0x80, 0x10,
     "02 80 17 00 BA 4C 4D 53 32 30 30 3B 33 30 31 30 36 33 3B 56 30 32 2E 31 30 20 10 22 61"),
    (0x3B, bytes.fromhex("B4003200"), 0x00, None, "02 00 05 00 3B B4 00 32 00 3B 1F"),
    (0xBB, bytes.fromhex("01B4003200"), 0x80, 0x10, "02 80 07 00 BB 01 B4 00 32 00 10 03 9D"),
    (0x77, bytes.fromhex("00000000000D0000000202") + bytes(21), 0x00, None,
     "02 00 21 00 77 00 00 00 00 00 0D 00 00 00 02 02" + " 00" * 21 + " 20 CB"),
    (0x32, b"", 0x00, None, "02 00 01 00 32 16 12"),
    (0xA0, b"\x00", 0x80, 0x00, "02 80 03 00 A0 00 00 06 0A"),
]  # fmt: skip


@pytest.mark.parametrize(("cmd", "data", "adr", "status", "hexstr"), SPEC_TELEGRAMS)
def test_spec_telegrams_encode_and_decode(
    cmd: int, data: bytes, adr: int, status: int | None, hexstr: str
) -> None:
    raw = bytes.fromhex(hexstr)
    assert sp.build_telegram(cmd, data, address=adr, status=status) == raw
    assert sp.check_telegram(raw)
    p = sp.TelegramParser(device_side=status is None)
    (tel,) = p.feed(raw, 1.0)
    assert isinstance(tel, sp.Telegram)
    assert (tel.address, tel.cmd, tel.data, tel.status, tel.raw) == (adr, cmd, data, status, raw)


def test_listing_misprints_are_rejected() -> None:
    # Tab. 6-4 prints SICK_LMS with CRC 5F B2; the right one is BE C5 (§A.9)
    bad = bytes.fromhex("02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 5F B2")
    assert not sp.check_telegram(bad)
    p = sp.TelegramParser(device_side=True)
    assert p.feed(bad) == []
    assert p.stats.crc_errors == 1


def test_fixture_pls_const_500cm() -> None:
    raw = bytes.fromhex(FIX["pls_b0_361_const500cm_status00"])
    assert len(raw) == 732 and raw[:7] == bytes.fromhex("0280D602B06901")
    (tel,) = sp.TelegramParser().feed(raw, 3.0)
    assert isinstance(tel, sp.Telegram)
    scan = sp.decode_scan(tel, variant="pls", seq=7)
    assert len(scan) == 361 and scan.seq == 7 and tel.status == 0x00
    np.testing.assert_array_equal(scan.ranges, np.full(361, 5.0))
    assert scan.angles[0] == pytest.approx(-math.pi / 2) and scan.angles[-1] == pytest.approx(
        math.pi / 2
    )
    assert scan.angles[180] == pytest.approx(0.0, abs=1e-12)
    assert np.diff(scan.angles) == pytest.approx(np.full(360, math.radians(0.5)))
    assert scan.flags is not None and not scan.flags.any()
    assert sp.encode_measured(np.full(361, 5.0), status=0x00) == raw


def test_fixture_lms_const_500cm_status10() -> None:
    raw = bytes.fromhex(FIX["lms_b0_361_const500cm_status10"])
    (tel,) = sp.TelegramParser().feed(raw)
    assert isinstance(tel, sp.Telegram) and tel.status == 0x10
    scan = sp.decode_scan(tel, variant="lms")
    np.testing.assert_array_equal(scan.ranges, 5.0)
    assert sp.encode_measured(np.full(361, 5.0), status=0x10) == raw


def test_fixture_pls_ramp() -> None:
    raw = bytes.fromhex(FIX["pls_b0_361_ramp100_status00"])
    assert raw.endswith(bytes.fromhex("CC0100B748"))
    (tel,) = sp.TelegramParser().feed(raw)
    assert isinstance(tel, sp.Telegram)
    scan = sp.decode_scan(tel)
    np.testing.assert_allclose(scan.ranges, (100 + np.arange(361)) / 100.0)
    assert sp.encode_measured((100 + np.arange(361)) / 100.0) == raw


def test_fixture_lms_181_mm() -> None:
    raw = bytes.fromhex(FIX["lms_b0_181_mm_const1234_status10"])
    assert len(raw) == 372 and raw[5:7] == bytes.fromhex("B540")
    (tel,) = sp.TelegramParser().feed(raw)
    assert isinstance(tel, sp.Telegram)
    mv = sp.parse_measured(tel.data)
    assert mv.count == 181 and mv.unit_m == 0.001
    scan = sp.decode_scan(tel, variant="lms")
    np.testing.assert_allclose(scan.ranges, 1.234)
    assert np.diff(scan.angles) == pytest.approx(np.full(180, math.radians(1.0)))
    assert sp.encode_measured(np.full(181, 1.234), unit_m=0.001, status=0x10) == raw


def test_special_codes_and_flags() -> None:
    vals = np.array(
        [0x1FFF, 0x1FFE, 0x1FFB, 0x1FF7, 0, 250, 250 | 0x2000, 250 | 0x4000, 250 | 0x8000],
        np.uint16,
    )
    data = bytes([len(vals), 0]) + vals.astype("<u2").tobytes()
    tel = sp.Telegram(0x80, 0xB0, data, 0)
    s = sp.decode_scan(tel, variant="pls")
    assert np.isinf(s.ranges[:5]).all()
    assert s.ranges[5:] == pytest.approx([2.5] * 4)
    assert s.flags is not None
    assert (s.flags[:5] & BEAM_NO_RETURN).all()
    assert s.flags[1] & BEAM_DAZZLE and s.flags[2] & BEAM_INVALID
    assert s.flags[6] == BEAM_DAZZLE and s.flags[7] == BEAM_FIELD_B and s.flags[8] == BEAM_FIELD_A
    assert s.valid_mask().tolist() == [False] * 5 + [True, False, True, True]


def test_flipped_reverses_angles() -> None:
    raw = bytes.fromhex(FIX["pls_b0_361_ramp100_status00"])
    (tel,) = sp.TelegramParser().feed(raw)
    assert isinstance(tel, sp.Telegram)
    s = sp.decode_scan(tel, flipped=True)
    assert s.angles[0] == pytest.approx(math.pi / 2)
    assert s.ranges[0] == pytest.approx(1.0)  # first value is now on the left


def test_decode_errors_are_documented_type() -> None:
    with pytest.raises(sp.SickProtocolError):
        sp.decode_scan(sp.Telegram(0x80, 0xA0, b"\x00", 0))
    with pytest.raises(sp.SickProtocolError):
        sp.parse_measured(b"\x10\x00\x01")  # announces 16 values, holds none
    with pytest.raises(sp.SickProtocolError):
        sp.build_telegram(0x20, bytes(900))


def test_stray_ack_nak_and_resync_on_bad_crc() -> None:
    good = bytes.fromhex("02 80 03 00 A0 00 10 16 0A")
    bad = bytearray(good)
    bad[5] ^= 0x01
    stream = b"\x06" + bytes(bad) + b"\x15\x99" + good
    p = sp.TelegramParser()
    ev = p.feed(stream, 0.0)
    kinds = [type(e).__name__ if not isinstance(e, sp.ByteEvent) else f"B{e.value:02x}" for e in ev]
    assert kinds == ["B06", "B15", "Telegram"]
    assert (
        p.stats.crc_errors == 1
        and p.stats.telegrams == 1
        and p.stats.acks == 1
        and p.stats.naks == 1
    )


def test_false_start_swallowing_a_real_telegram_is_recovered() -> None:
    good = bytes.fromhex(FIX["pls_b0_361_ramp100_status00"])
    # a false header announcing 700 bytes: the real telegram starts inside its "body"
    stream = bytes.fromhex("02 80 BC 02") + good + good
    p = sp.TelegramParser()
    out = [e for e in p.feed(stream) if isinstance(e, sp.Telegram)]
    assert len(out) == 2 and all(t.raw == good for t in out)
    assert p.stats.crc_errors >= 1 and p.buffered == 0


def test_length_bounds() -> None:
    p = sp.TelegramParser()
    p.feed(bytes.fromhex("02 80 FF 7F"))  # LEN 32767 > 812
    assert p.stats.length_errors == 1 and p.buffered < 4


def test_byte_by_byte_feeding_and_first_byte_stamp() -> None:
    raw = bytes.fromhex(FIX["pls_b0_361_const500cm_status00"])
    p = sp.TelegramParser(byte_time=0.001)
    out = []
    for i, b in enumerate(b"\x06\x06" + raw):
        out += p.feed(bytes([b]), 10.0 + i)
    tels = [e for e in out if isinstance(e, sp.Telegram)]
    assert len(tels) == 1 and tels[0].stamp == pytest.approx(12.0)


def test_stamp_is_backdated_within_a_chunk() -> None:
    raw = bytes.fromhex(FIX["pls_b0_361_const500cm_status00"])
    p = sp.TelegramParser(byte_time=11 / 38400)
    (tel,) = p.feed(raw, 100.0)
    assert isinstance(tel, sp.Telegram)
    assert tel.stamp == pytest.approx(100.0 - 731 * 11 / 38400)


def test_interleaved_garbage_finds_every_intact_telegram() -> None:
    rng = random.Random(5)
    frames = [sp.encode_measured(np.full(361, 1.0 + k / 100)) for k in range(60)]
    stream = bytearray()
    intact = []
    for k, f in enumerate(frames):
        stream += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 50)))
        if k % 7 == 3:
            b = bytearray(f)
            b[rng.randrange(4, len(b))] ^= 0x5A
            stream += b
        else:
            stream += f
            intact.append(k)
    p = sp.TelegramParser()
    got = []
    i = 0
    while i < len(stream):
        n = rng.randrange(1, 900)
        got += [
            e
            for e in p.feed(bytes(stream[i : i + n]))
            if isinstance(e, sp.Telegram) and e.cmd == 0xB0
        ]
        i += n
    ks = [round((sp.decode_scan(t).ranges[0] - 1.0) * 100) for t in got]
    assert ks == intact


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.binary(max_size=400), max_size=12))
def test_fuzz_parser_never_raises_and_stays_bounded(chunks: list[bytes]) -> None:
    p = sp.TelegramParser()
    for c in chunks:
        for ev in p.feed(c):
            if isinstance(ev, sp.Telegram):
                assert sp.check_telegram(ev.raw)
                try:
                    sp.decode_scan(ev)
                except sp.SickProtocolError:
                    pass
        assert p.buffered < sp.MAX_TELEGRAM


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 0x3FF), st.binary(max_size=40))
def test_fuzz_valid_telegram_inside_noise_is_found(prefix: bytes, n: int, suffix: bytes) -> None:
    n = min(n, 400)
    frame = sp.encode_measured(np.arange(n) / 100.0)
    p = sp.TelegramParser()
    out = p.feed(prefix + frame + suffix) + p.feed(frame)
    tels = [e for e in out if isinstance(e, sp.Telegram) and e.raw == frame]
    assert len(tels) >= 1  # the second copy is always found even if noise swallowed the first
    assert p.buffered < sp.MAX_TELEGRAM


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0.0, 80.0), min_size=1, max_size=401))
def test_encode_decode_roundtrip(ranges: list[float]) -> None:
    r = np.array(ranges)
    (tel,) = sp.TelegramParser().feed(sp.encode_measured(r))
    assert isinstance(tel, sp.Telegram)
    s = sp.decode_scan(tel, variant="lms", max_range=100.0)
    q = np.rint(r / 0.01)
    ok = (q > 0) & (q < 0x1FF7)
    np.testing.assert_allclose(s.ranges[ok], q[ok] * 0.01)
    assert np.isinf(s.ranges[~ok]).all()
