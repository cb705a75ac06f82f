"""Damage a CARMEN log the way real logs are damaged (used by the reader and replay tests).

Every damage class of issue 14: impossible readings (NaN, negative, absurd), torn lines,
binary garbage lines, wrong beam counts, NaN odometry and NaN scan stamps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DAMAGE_CLASSES = ("readings", "torn", "garbage", "beam_count", "nan_odometry", "nan_stamp")


@dataclass
class Damaged:
    data: bytes
    #: scan lines (0-based, in the original file) that can no longer be read
    lost_scans: set[int] = field(default_factory=set)
    #: damaged lines the reader must skip (1-based line numbers in the damaged file)
    malformed_lines: list[int] = field(default_factory=list)
    #: impossible readings written, by kind
    readings: dict[str, int] = field(default_factory=dict)
    nan_stamps: int = 0


def damage(
    text: str,
    rng: np.random.Generator,
    *,
    reading_share: float = 0.01,
    torn: int = 4,
    garbage: int = 3,
    beam_counts: int = 2,
    nan_odometry: int = 2,
    nan_stamps: int = 1,
) -> Damaged:
    """``text`` (a FLASER or ROBOTLASER1 + ODOM log from ``write_carmen``) with the given
    damage."""
    lines = text.split("\n")
    scan_rows = [i for i, ln in enumerate(lines) if ln.startswith(("FLASER ", "ROBOTLASER1 "))]
    # the beam count's token: FLASER n ...; ROBOTLASER1 type start fov res max acc mode n ...
    nk = 1 if lines[scan_rows[0]].startswith("FLASER ") else 8
    odom_rows = [i for i, ln in enumerate(lines) if ln.startswith("ODOM ")]
    out = Damaged(b"")
    kinds = {"NaN": 0, "negative": 0, "beyond max range": 0}
    # impossible readings, spread over all scans
    for i in scan_rows:
        t = lines[i].split(" ")
        n = int(t[nk])
        hit = np.flatnonzero(rng.random(n) < reading_share)
        for k in hit:
            kind = ("NaN", "negative", "beyond max range")[int(rng.integers(3))]
            t[nk + 1 + k] = {"NaN": "nan", "negative": "-0.01", "beyond max range": "123456.7"}[kind]
            kinds[kind] += 1
        lines[i] = " ".join(t)
    out.readings = {k: v for k, v in kinds.items() if v}
    picks = rng.choice(len(scan_rows), torn + beam_counts + nan_stamps, replace=False)
    for j in picks[:torn]:  # torn: the line ends part-way (the rest of the write was lost)
        i = scan_rows[int(j)]
        cut = int(rng.integers(8, len(lines[i]) - 30))
        lines[i] = lines[i][:cut]
        out.lost_scans.add(i)
    for j in picks[torn : torn + beam_counts]:  # count says one beam more than written
        i = scan_rows[int(j)]
        t = lines[i].split(" ")
        t[nk] = str(int(t[nk]) + 1)
        lines[i] = " ".join(t)
        out.lost_scans.add(i)
    for j in picks[torn + beam_counts :]:  # the scan's stamps are NaN: kept, stamp repaired
        i = scan_rows[int(j)]
        t = lines[i].split(" ")
        t[-3] = "nan"
        t[-1] = "nan"
        lines[i] = " ".join(t)
        out.nan_stamps += 1
    for j in rng.choice(len(odom_rows), nan_odometry, replace=False):
        i = odom_rows[int(j)]
        t = lines[i].split(" ")
        t[1] = "nan"
        lines[i] = " ".join(t)
    raw = [ln.encode("latin-1") for ln in lines]
    marks = set(out.lost_scans)
    # binary garbage lines inserted between messages (never at the very top: the header
    # and the first messages identify the format)
    where = sorted(rng.choice(np.arange(len(raw) // 4, len(raw) - 1), garbage, replace=False))
    junk_rows: list[int] = []
    for shift, w in enumerate(where):
        blob = bytes(int(b) for b in rng.integers(0, 256, int(rng.integers(20, 200))))
        blob = blob.replace(b"\n", b"\x00")
        raw.insert(int(w) + shift, blob)
        junk_rows.append(int(w) + shift)
    # 1-based line numbers of every malformed line in the damaged file
    orig = list(range(len(lines)))
    for r in junk_rows:
        orig.insert(r, -1)
    for ln, i in enumerate(orig, 1):
        if i == -1 or i in marks or (i >= 0 and lines[i].startswith("ODOM nan")):
            out.malformed_lines.append(ln)
    out.data = b"\n".join(raw)
    return out
