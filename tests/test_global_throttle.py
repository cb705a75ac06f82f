"""While lost without a lock in sight (a log from another building), the global search is
throttled (``localizer.global_search_every`` scans and ``global_search_interval`` s of
scan time between searches) while the hypotheses are still tracked on every scan; only a
leader that has dominated long enough is verified by a search at once."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from icploc import sim as worlds
from icploc.config import ConfigError, LocalizerConfig
from icploc.localizer import Localizer, Status
from icploc.maps import Map
from icploc.relocalize import Relocalizer, attach, global_localizer

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benches"))
import global_bench as gb  # noqa: E402


class CountingGlob:
    """A GlobalLocalizer that records the scan index and stamp of every search."""

    def __init__(self, glob: Any, loc: list[Localizer]) -> None:
        self.glob = glob
        self.loc = loc
        self.searches: list[tuple[int, float]] = []
        #: searches that verified a dominating leader (they skip the throttle)
        self.verifications = 0
        self.refines = 0

    def search(self, *a: Any, **k: Any) -> Any:
        loc = self.loc[0]
        if loc.recovery.relocalizer.awaiting_verification:
            self.verifications += 1
        else:
            self.searches.append((loc.scans_processed, self.stamp))
        return self.glob.search(*a, **k)

    def refine(self, *a: Any, **k: Any) -> Any:
        self.refines += 1
        return self.glob.refine(*a, **k)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.glob, name)


@pytest.fixture(scope="module")
def foreign() -> dict:
    """Lab scans (12.5 Hz) against the map of a 40 x 20 m office building: never locks."""
    w = worlds.lab(people=0)
    frames = list(worlds.simulate(w, worlds.lab_random_walk(8.0, seed=5), seed=6, max_frames=90))
    bld = gb.building()
    return {"frames": frames, "glob": global_localizer(bld.walls, 0.05), "map": bld.walls}


def _run(foreign: dict, **localizer: Any) -> tuple[list[Any], CountingGlob, int]:
    cfg = LocalizerConfig().replace(localizer=localizer) if localizer else LocalizerConfig()
    holder: list[Localizer] = []
    glob = CountingGlob(foreign["glob"], holder)
    loc = Localizer(Map.from_lines(foreign["map"]), cfg)
    holder.append(loc)
    attach(loc, Relocalizer(None, localizer=glob))
    rec = loc.recovery
    hook = rec.recover
    calls = [0]

    def counted(view: Any, points: Any) -> Any:
        calls[0] += 1
        glob.stamp = float(view.stamp)
        return hook(view, points)

    rec.recover = counted  # type: ignore[method-assign]
    ests = []
    for f in foreign["frames"]:
        loc.add_odometry(f.odometry)
        ests.append(loc.update(f.scan))
    return ests, glob, calls[0]


def test_search_is_throttled_while_lost_and_hypotheses_still_tracked(foreign: dict) -> None:
    frames = foreign["frames"]
    ests, glob, calls = _run(foreign)
    lc = LocalizerConfig().localizer
    assert len(ests) == len(frames)
    assert all(e.status is Status.LOST for e in ests)  # the wrong building: never a lock
    assert all(np.isfinite(e.pose).all() for e in ests)
    idx = [k for k, _ in glob.searches]
    stamps = [t for _, t in glob.searches]
    assert idx[0] == 0  # the very first scan searches
    assert np.all(np.diff(idx) >= lc.global_search_every)
    assert np.all(np.diff(stamps) >= lc.global_search_interval)
    # it keeps searching now and then, but far less than once per scan ...
    assert 3 <= len(idx) <= len(frames) // lc.global_search_every + 1
    # ... and verifying a leader (never found in the wrong building) stays rare
    assert glob.verifications <= len(idx) + 2
    # ... and between searches the hypotheses are carried and re-scored
    assert calls > 2 * len(idx) and glob.refines > len(idx)


def test_unthrottled_searches_on_every_call(foreign: dict) -> None:
    _, throttled, _ = _run(foreign)
    ests, glob, calls = _run(foreign, global_search_every=1, global_search_interval=0.0)
    assert all(e.status is Status.LOST for e in ests)
    assert len(glob.searches) + glob.verifications == calls  # the previous behaviour
    assert len(glob.searches) > 3 * len(throttled.searches)


def test_search_interval_in_scan_time(foreign: dict) -> None:
    _, glob, _ = _run(foreign, global_search_every=1, global_search_interval=2.0)
    stamps = [t for _, t in glob.searches]
    duration = foreign["frames"][-1].scan.stamp - foreign["frames"][0].scan.stamp
    assert np.all(np.diff(stamps) >= 2.0)
    assert 2 <= len(stamps) <= duration / 2.0 + 1


@pytest.mark.parametrize(
    "bad", [{"global_search_every": 0}, {"global_search_interval": -1.0},
            {"global_search_interval": float("nan")}],
)  # fmt: skip
def test_throttle_settings_are_validated(bad: dict) -> None:
    with pytest.raises(ConfigError):
        LocalizerConfig().replace(localizer=bad).validate()
