"""Parse throughput of the serial protocol stacks (pure Python, one core).

    .venv/bin/python benches/parse_throughput.py [--seconds 2] [--chunk 4096] [--json]

* PLS: 732-byte B0 telegrams (361 values) fed in ``--chunk``-byte reads through
  ``TelegramParser`` (framing + CRC), then ``decode_scan`` (→ ``Scan``); also with 5 %
  corrupted telegrams and random garbage between them.
* PowerBot: standard SIPs (with 4 sonar readings) through ``PacketParser`` + ``SipDecoder``.

Real-time needs: a PLS at 38400 Bd 8E1 delivers ~4.8 telegrams/s (500 kBd: ~62/s);
a PowerBot sends 10 SIPs/s.
"""

from __future__ import annotations

import argparse
import json
import random
import time
from collections.abc import Callable

import numpy as np
from icploc.drivers import arcos_protocol as ap
from icploc.drivers import sick_protocol as sp


def _rate(fn: Callable[[], int], seconds: float) -> float:
    n = 0
    t0 = time.perf_counter()
    while True:
        n += fn()
        dt = time.perf_counter() - t0
        if dt >= seconds:
            return n / dt


def _chunks(stream: bytes, size: int) -> list[bytes]:
    return [stream[i : i + size] for i in range(0, len(stream), size)]


def pls_stream(n: int, corrupt: float, garbage: float, seed: int = 1) -> bytes:
    rng = random.Random(seed)
    out = bytearray()
    for k in range(n):
        frame = bytearray(sp.encode_measured(1.0 + 0.01 * ((np.arange(361) + k) % 500)))
        if rng.random() < garbage:
            out += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
        if rng.random() < corrupt:
            frame[rng.randrange(len(frame))] ^= 0x41
        out += frame
    return bytes(out)


def bench_pls(
    seconds: float, chunk: int, corrupt: float = 0.0, garbage: float = 0.0, decode: bool = True
) -> float:
    chunks = _chunks(pls_stream(200, corrupt, garbage), chunk)

    def run() -> int:
        p = sp.TelegramParser(byte_time=11 / 38400)
        n = 0
        for c in chunks:
            for ev in p.feed(c, 0.0):
                if isinstance(ev, sp.Telegram) and ev.cmd == sp.REPLY_MEASURED:
                    if decode:
                        sp.decode_scan(ev)
                    n += 1
        return n

    return _rate(run, seconds)


def bench_sip(seconds: float, chunk: int) -> float:
    frames = bytearray()
    for k in range(500):
        raw = ap.RawSip(type=0x33, xpos=(k * 97) & 0x7FFF, ypos=(k * 13) & 0x7FFF, thpos=(k % 4096) - 2048,
                        lvel=300, rvel=320, battery=245, stall_bumpers=0, control=0, flags=1, compass=0,
                        sonar=tuple((d % 32, 1000 + d) for d in range(4 * k, 4 * k + 4)),
                        grip_state=0, anport=0, analog=0, digin=0, digout=0)  # fmt: skip
        frames += ap.build_sip(raw)
    chunks = _chunks(bytes(frames), chunk)

    def run() -> int:
        p = ap.PacketParser(byte_time=10 / 9600)
        d = ap.SipDecoder()
        n = 0
        for c in chunks:
            for pkt in p.feed(c, 0.0):
                if d.decode(pkt) is not None:
                    n += 1
        return n

    return _rate(run, seconds)


def main() -> None:
    ap_ = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap_.add_argument("--seconds", type=float, default=2.0, help="time per measurement")
    ap_.add_argument("--chunk", type=int, default=4096, help="bytes per simulated read()")
    ap_.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap_.parse_args()
    res = {
        "pls_telegrams_per_s_parse_only": bench_pls(a.seconds, a.chunk, decode=False),
        "pls_scans_per_s_parse_and_decode": bench_pls(a.seconds, a.chunk),
        "pls_scans_per_s_5pct_corrupt_plus_garbage": bench_pls(
            a.seconds, a.chunk, corrupt=0.05, garbage=0.5
        ),
        "powerbot_sips_per_s_parse_and_decode": bench_sip(a.seconds, a.chunk),
    }
    if a.json:
        print(json.dumps({k: round(v, 1) for k, v in res.items()}))
    else:
        for k, v in res.items():
            print(f"{k:48s} {v:10.0f}")


if __name__ == "__main__":
    main()
