"""A global search's own coarse floor (``GlobalLocalizer.search(min_score=...)``) and the
kidnap / lock check that uses it (``GlobalRelocalization.check_pose``): the check searches
only for poses that could change its verdict, and decides as the plain search does."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from icploc import InvalidInputError
from icploc.config import LocalizerConfig
from icploc.localizer import prepare_scan
from icploc.relocalize import GlobalRelocalization, Relocalizer, global_localizer

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benches"))
import global_bench as gb  # noqa: E402

SENSOR = gb.Sensor()
CFG = LocalizerConfig()


class Spy:
    """A GlobalLocalizer that records each search's floor and nodes."""

    def __init__(self, glob: Any) -> None:
        self.glob = glob
        self.calls: list[tuple[float | None, int]] = []

    def search(self, *a: Any, **k: Any) -> Any:
        r = self.glob.search(*a, **k)
        self.calls.append((k.get("min_score"), r.nodes))
        return r

    def __getattr__(self, name: str) -> Any:
        return getattr(self.glob, name)


@pytest.fixture(scope="module")
def bld() -> Any:
    return gb.building()


@pytest.fixture(scope="module")
def glob(bld: Any) -> Any:
    return global_localizer(bld.walls, 0.05)


def test_a_floor_keeps_the_candidates_above_it_and_prunes_below(bld, glob) -> None:  # noqa: ANN001
    rng = np.random.default_rng(5)
    pts = prepare_scan(gb.scan_at(bld, (21.75, 16.83, 1.571), 0.0, SENSOR, rng), CFG)
    plain = glob.search(pts)
    top = max(c.coarse_score for c in plain.candidates)
    for f in (0.5 * top, 0.8 * top):  # at most accept_ratio x the best leaf: the same result
        r = glob.search(pts, min_score=f)
        assert [c.pose for c in r.candidates] == [c.pose for c in plain.candidates]
        assert r.leaves == plain.leaves
    high = glob.search(pts, min_score=0.95 * top)  # prunes the leaves between
    assert 1 <= len(high.candidates) <= len(plain.candidates)
    assert all(c.coarse_score >= 0.95 * top - 1e-9 for c in high.candidates)
    assert high.nodes < 0.9 * plain.nodes, (high.nodes, plain.nodes)
    none = glob.search(pts, min_score=min(0.999, 1.01 * top))
    assert not none.candidates and none.nodes * 4 < plain.nodes
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(InvalidInputError, match="min_score"):
            glob.search(pts, min_score=bad)


def test_a_floored_check_decides_as_the_plain_one_with_fewer_nodes(bld, glob) -> None:  # noqa: ANN001
    """Tracked poses right, a little off, in the office across the corridor, and a scan of
    clutter that fits nowhere: the verdict and pose of every check (tracking and strict)
    are the plain search's, each floored search got a floor above the configured one, and
    the floored checks visit fewer nodes in all."""
    spy = Spy(glob)
    checker = GlobalRelocalization(Relocalizer(None, localizer=spy), config=CFG)
    rng = np.random.default_rng(11)
    truths = [(21.75, 16.83, 1.571), (5.79, 12.21, -0.25), (16.64, 10.24, 1.73)]
    wrong = {0: (21.13, 6.87, 2.033), 1: (16.64, 10.24, 1.73), 2: (5.79, 12.21, -0.25)}
    cases = []
    for k, truth in enumerate(truths):
        pts = prepare_scan(gb.scan_at(bld, truth, 0.0, SENSOR, rng), CFG)
        off = (truth[0] + 0.1, truth[1] - 0.05, truth[2] + 0.02)
        cases += [(pts, truth), (pts, off), (pts, wrong[k])]
    clutter = rng.uniform(-6.0, 6.0, size=(300, 2))
    cases.append((clutter, truths[0]))
    verdicts = []
    nodes = {True: 0, False: 0}
    for pts, tracked in cases:
        for strict in (False, True):
            got = {}
            for floored in (True, False):
                spy.calls.clear()
                got[floored] = checker.check_pose(glob.index, pts, tracked, strict, floored)
                nodes[floored] += sum(n for _, n in spy.calls)
                if floored:
                    assert spy.calls[0][0] is not None
                    assert spy.calls[0][0] > checker.global_search.min_score
                else:
                    assert [f for f, _ in spy.calls] == [None]
            a, b = got[True], got[False]
            assert (a.verdict, a.pose, a.here) == (b.verdict, b.pose, b.here)
            if a.verdict == "unsure":  # the best pose searched: below the confirming minimum
                assert max(a.best, b.best) < checker.relocalizer.config.min_score
            else:
                assert a.best == b.best
            verdicts.append(a.verdict)
    assert "elsewhere" in verdicts and "" in verdicts, verdicts
    assert nodes[True] < 0.9 * nodes[False], nodes
