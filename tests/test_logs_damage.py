"""hypothesis through the log readers with every damage class of issue 14: the lenient
reader keeps every intact scan and never raises; ``strict`` raises naming a damaged line."""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from icploc.logs import LogFormatError, open_log
from icploc.logs.carmen import flaser_angles, read_carmen, write_carmen
from icploc.messages import BEAM_INVALID, Odometry, Scan
from log_damage import DAMAGE_CLASSES, damage

N_SCANS = 40


def _clean_text(tmp_path: Path, fmt: str = "FLASER") -> str:
    rng = np.random.default_rng(0)
    ang = flaser_angles(181)
    scans = [
        Scan(stamp=1.0 + 0.2 * k, ranges=rng.uniform(0.5, 7.0, 181), angles=ang, max_range=8.0)
        for k in range(N_SCANS)
    ]
    odoms = [Odometry(0.95 + 0.1 * k, (0.01 * k, 0.0, 0.001 * k)) for k in range(2 * N_SCANS + 2)]
    p = tmp_path / "clean.log"
    write_carmen(p, scans, odoms, precision=3, fmt=fmt)
    return p.read_text()


CLASS_ARGS = {
    "readings": {"reading_share": 0.02},
    "torn": {"torn": 3},
    "garbage": {"garbage": 3},
    "beam_count": {"beam_counts": 2},
    "nan_odometry": {"nan_odometry": 2},
    "nan_stamp": {"nan_stamps": 1},
}
NONE = {
    "reading_share": 0.0, "torn": 0, "garbage": 0, "beam_counts": 0, "nan_odometry": 0,
    "nan_stamps": 0,
}  # fmt: skip

damage_sets = st.sets(st.sampled_from(DAMAGE_CLASSES), min_size=1)
hyp = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def _damaged(  # type: ignore[no-untyped-def]
    tmp_path: Path, classes: set[str], seed: int, gz: bool = False, fmt: str = "FLASER"
):
    kw = dict(NONE)
    for c in classes:
        kw.update(CLASS_ARGS[c])
    dm = damage(_clean_text(tmp_path, fmt), np.random.default_rng(seed), **kw)  # type: ignore[arg-type]
    p = tmp_path / ("d.log.gz" if gz else "d.log")
    p.write_bytes(gzip.compress(dm.data) if gz else dm.data)
    return p, dm


formats = st.sampled_from(["FLASER", "ROBOTLASER1"])


@hyp
@given(classes=damage_sets, seed=st.integers(0, 2**32 - 1), gz=st.booleans(), fmt=formats)
def test_lenient_reader_keeps_every_intact_scan(
    tmp_path: Path, classes: set[str], seed: int, gz: bool, fmt: str
) -> None:
    p, dm = _damaged(tmp_path, classes, seed, gz, fmt)
    d = open_log(p)
    assert len(d.scans) == N_SCANS - len(dm.lost_scans)


@hyp
@given(classes=damage_sets, seed=st.integers(0, 2**32 - 1), fmt=formats)
def test_lenient_reader_output_is_usable(
    tmp_path: Path, classes: set[str], seed: int, fmt: str
) -> None:
    """Every beam is a real reading or inf; every stamp and pose finite; scans in order."""
    p, _ = _damaged(tmp_path, classes, seed, fmt=fmt)
    d = read_carmen(p)
    ranges = np.concatenate([s.ranges for s in d.scans])
    stamps = np.array([s.stamp for s in d.scans])
    odo = np.array([(o.stamp, *o.pose) for o in d.odometry])
    ok = (
        bool(np.all((ranges >= 0) & ((ranges <= 8.0) | np.isinf(ranges))))
        and bool(np.all(np.isfinite(stamps)) and np.all(np.diff(stamps) >= 0))
        and bool(np.all(np.isfinite(odo)))
    )
    assert ok


@hyp
@given(seed=st.integers(0, 2**32 - 1))
def test_impossible_readings_are_flagged_invalid(tmp_path: Path, seed: int) -> None:
    p, _ = _damaged(tmp_path, {"readings"}, seed)
    d = read_carmen(p)
    flagged = sum(int(np.count_nonzero(s.flags & BEAM_INVALID)) for s in d.scans)
    assert flagged == sum(d.info.invalid_readings.values())


@hyp
@given(classes=damage_sets, seed=st.integers(0, 2**32 - 1), fmt=formats)
def test_lenient_reader_lists_the_malformed_lines(
    tmp_path: Path, classes: set[str], seed: int, fmt: str
) -> None:
    p, dm = _damaged(tmp_path, classes, seed, fmt=fmt)
    info = read_carmen(p).info
    assert [ln for ln, _ in info.dropped] == sorted(dm.malformed_lines)[:10]


@hyp
@given(classes=damage_sets, seed=st.integers(0, 2**32 - 1), fmt=formats)
def test_strict_reader_raises_at_a_damaged_line(
    tmp_path: Path, classes: set[str], seed: int, fmt: str
) -> None:
    p, dm = _damaged(tmp_path, classes, seed, fmt=fmt)
    with pytest.raises(LogFormatError) as ei:
        read_carmen(p, strict=True)
    assert ei.value.line is None or ei.value.line in _damaged_lines(p, dm)


def _damaged_lines(p: Path, dm) -> set[int]:  # type: ignore[no-untyped-def]
    """Lines holding any damage (malformed lines, impossible readings, NaN stamps)."""
    lines = p.read_bytes().split(b"\n")
    bad = set(dm.malformed_lines)
    for k, ln in enumerate(lines, 1):
        if ln.startswith((b"FLASER", b"ROBOTLASER1")) and (b"nan" in ln or b" -0.01 " in ln or b"123456.7" in ln):
            bad.add(k)
    return bad


def test_gzip_bomb_is_refused_without_reading_it_whole(tmp_path: Path) -> None:
    """Issue 14: a 2 GB gzip bomb was read whole. The bound stops the stream early."""
    p = tmp_path / "bomb.log.gz"
    with gzip.open(p, "wb", compresslevel=1) as fh:
        fh.write(b"FLASER 3 1 2 3 0 0 0 0 0 0 1.0 h 1.0\n")
        zeros = b" " * (1 << 20)
        for _ in range(64):
            fh.write(zeros)
    with pytest.raises(LogFormatError, match="decompresses to more than 16,777,216 bytes"):
        read_carmen(p, max_bytes=16 << 20)


def test_gzip_cut_short_keeps_the_scans_before_the_cut(tmp_path: Path) -> None:
    lines = [f"FLASER 3 1 2 3 0 0 0 0 0 0 {k + 1.0} h {k + 1.0}" for k in range(2000)]
    full = gzip.compress(("\n".join(lines) + "\n").encode())
    p = tmp_path / "cut.log.gz"
    p.write_bytes(full[: len(full) * 3 // 4])
    d = read_carmen(p)
    assert len(d.scans) > 100 and d.info.n_dropped >= 1


def test_gzip_cut_short_refused_when_strict(tmp_path: Path) -> None:
    lines = [f"FLASER 3 1 2 3 0 0 0 0 0 0 {k + 1.0} h {k + 1.0}" for k in range(2000)]
    full = gzip.compress(("\n".join(lines) + "\n").encode())
    p = tmp_path / "cut.log.gz"
    p.write_bytes(full[: len(full) * 3 // 4])
    with pytest.raises(LogFormatError, match="gzip"):
        read_carmen(p, strict=True)


def test_saturation_value_found_under_a_tail_of_absurd_readings(tmp_path: Path) -> None:
    """A few impossible readings above the 81.91 no-return value do not hide it."""
    rng = np.random.default_rng(1)
    ang = flaser_angles(180)
    scans = []
    for k in range(60):
        r = rng.uniform(0.5, 7.0, 180)
        r[rng.random(180) < 0.2] = 81.91
        if k % 2:
            r[k % 180] = 150.0 + k  # an impossible, never repeated reading
        scans.append(Scan(stamp=1.0 + k, ranges=r, angles=ang))
    p = tmp_path / "sat.log"
    write_carmen(p, scans, precision=3)
    text = "\n".join(ln for ln in p.read_text().split("\n") if not ln.startswith("PARAM"))
    p.write_text(text)
    d = read_carmen(p)
    assert math.isclose(d.info.max_range, 81.91 - 0.25)


@pytest.mark.parametrize(("fmt", "cut"), [("ROBOTLASER1", "ROBOTLASE"), ("FLASER", "FLAS")])
def test_a_line_torn_inside_its_type_word_is_listed_as_malformed(
    tmp_path: Path, fmt: str, cut: str
) -> None:
    """A write that stopped inside the first word (``ROBOTLASE``) is damage at that line, not
    an unknown message type skipped in silence (hypothesis found it: seed 267789403)."""
    lines = _clean_text(tmp_path, fmt).split("\n")
    k = next(i for i, ln in enumerate(lines) if ln.startswith(fmt))
    lines[k] = cut
    p = tmp_path / "torn.log"
    p.write_text("\n".join(lines))
    dropped = read_carmen(p).info.dropped
    assert [(ln, cut in why) for ln, why in dropped] == [(k + 1, True)]
