"""The outside-the-map state (icploc.outside): recognised from the scan, coasted on
odometry, left again by a verified lock; on a simulated building whose map lacks a wing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from icploc.outside import MappedArea, OutsideConfig
from partial_world import cached_run, errors, half_known_grid, localized


def test_mapped_area_says_unknown_cells_and_beyond_the_grid_are_unmapped() -> None:
    area = MappedArea.of(half_known_grid(), None, OutsideConfig(margin=0.0))
    xy = np.array([[1.0, 2.0], [3.0, 2.0], [9.0, 2.0], [-5.0, 0.0]])
    assert area.unmapped(xy).tolist() == [False, True, True, True]


def test_mapped_area_of_a_point_map_reaches_a_metre_from_its_points() -> None:
    from icploc._core import MapIndex

    pts = np.column_stack([np.linspace(0.0, 5.0, 51), np.zeros(51)])
    area = MappedArea.of(pts, MapIndex(pts), OutsideConfig(reach=1.0))
    xy = np.array([[2.5, 0.6], [2.5, 2.5]])
    assert area.unmapped(xy).tolist() == [False, True]


def test_unmapped_share_is_the_share_of_points_on_unmapped_space() -> None:
    area = MappedArea.of(half_known_grid(), None, OutsideConfig(margin=0.0))
    pts = np.array([[0.5, 0.0], [1.0, 0.0], [2.5, 0.0], [3.0, 0.0]])  # robot frame
    assert area.unmapped_share(pts, (0.0, 2.0, 0.0)) == pytest.approx(0.5)


def test_outside_config_refuses_an_exit_share_above_the_enter_share() -> None:
    with pytest.raises(ValueError, match="exit_share"):
        OutsideConfig(enter_share=0.3, exit_share=0.5).validate()


# -- the simulated building whose map lacks a wing (slow: one run shared by the tests) --


@pytest.mark.slow
def test_no_scan_claims_tracking_more_than_half_a_metre_off() -> None:
    run, _, ests, _ = localized()
    e = errors(run, ests)
    tracking = np.array([x.status.value == "tracking" for x in ests])
    assert int(np.sum(tracking & (e > 0.5))) == 0


@pytest.mark.slow
def test_the_wing_room_is_reported_outside_the_map() -> None:
    run, _, ests, _ = localized()
    deep = run.truth[:, 0] > 21.5  # in the wing's room, away from the corridor
    mapped = np.array([x.mapped for x in ests])
    assert float(np.mean(~mapped[deep])) >= 0.95


@pytest.mark.slow
def test_outside_scans_are_never_tracking_and_say_outside_map() -> None:
    _, _, ests, _ = localized()
    out = [x for x in ests if not x.mapped]
    assert {(x.status.value, x.reason) for x in out} <= {
        ("degraded", "outside_map"),
        ("lost", "outside_map"),
    }


@pytest.mark.slow
def test_outside_the_pose_is_the_calibrated_odometry_prediction() -> None:
    _, _, ests, _ = localized()
    out = [x for x in ests if not x.mapped]
    assert max(math.dist(x.pose[:2], x.prediction[:2]) for x in out) == 0.0


@pytest.mark.slow
def test_outside_the_heading_variance_grows_scan_by_scan() -> None:
    # (the position variance may shrink on the way back: a heading error driven out and
    # back cancels, and the covariance knows it; the heading's only grows)
    _, _, ests, _ = localized()
    runs: list[list[float]] = [[]]
    for x in ests:  # the runs of consecutive scans outside
        if x.mapped:
            runs.append([])
        else:
            runs[-1].append(float(x.covariance[2, 2]))
    var = max(runs, key=len)
    assert [len(var) > 100, all(b >= a for a, b in zip(var, var[1:], strict=False))] == [True] * 2


@pytest.mark.slow
def test_outside_the_position_variance_ends_far_wider_than_it_began() -> None:
    _, _, ests, _ = localized()
    runs: list[list[float]] = [[]]
    for x in ests:
        if x.mapped:
            runs.append([])
        else:
            runs[-1].append(float(np.trace(x.covariance[:2, :2])))
    trace = max(runs, key=len)
    assert trace[-1] > 10.0 * trace[0]


@pytest.mark.slow
def test_the_robot_comes_back_into_the_map_once_with_a_counted_reentry() -> None:
    _, _, _, mon = localized()
    got = [(s.closed, s.reentry_scans is not None and s.reentry_scans > 0) for s in mon.stretches]
    assert got == [(True, True)]


@pytest.mark.slow
def test_after_reentry_the_hall_is_tracked_as_on_the_way_out() -> None:
    run, _, ests, mon = localized()
    e = errors(run, ests)
    back = mon.stretches[0].end + 20
    assert float(np.percentile(e[back:], 95)) <= 0.10


@pytest.mark.slow
def test_no_match_and_no_search_runs_while_outside() -> None:
    _, _, ests, _ = localized()
    out = [x for x in ests if not x.mapped]
    assert [(x.iterations, x.hypotheses, x.measurement) for x in out] == [(0, (), None)] * len(out)


def test_the_estimates_csv_says_a_scan_was_outside_the_map(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import csv

    from icploc.localizer import Estimate, Status
    from icploc.trajectory import EstimatesWriter

    e = Estimate(1.0, (1.0, 2.0, 0.0), np.eye(3) * 1e-2, Status.DEGRADED, float("nan"), 0, 0.0,
                 reason="outside_map", mapped=False)  # fmt: skip
    with EstimatesWriter(tmp_path / "e.csv") as w:
        w.write(e)
    row = next(csv.DictReader((tmp_path / "e.csv").read_text().splitlines()))
    assert [row["status"], row["reason"], row["mapped"]] == ["degraded", "outside_map", "0"]


def test_the_reference_observer_changes_no_estimate() -> None:
    # benches/eval_partial.py's observer (verify_pose at the reference pose on every
    # re-entering scan) sits on the monitor instance: the estimates are the same without it
    import sys
    from pathlib import Path

    from icploc.localizer import Localizer, run
    from icploc.outside import attach

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benches"))
    import eval_partial as ep

    r, m = cached_run()
    items = r.items[: 2 * 3100]  # to just past the re-entry lock (scan ~3057)
    got = []
    explained: dict[int, bool] = {}
    for observer in (None, ep.reentry_observer(r.truth, explained)):
        loc = Localizer(m, initial_pose=tuple(r.truth[0]))
        mon = attach(loc, record=True, observer=observer)
        got.append((run(loc, items), mon))
    (plain, mon0), (watched, mon1) = got
    assert len(explained) > 10  # the observer ran on the re-entering scans
    assert [s.end for s in mon0.stretches] == [s.end for s in mon1.stretches]
    assert len(plain) == len(watched)
    assert [(e.pose, e.status, e.reason, e.mapped) for e in plain] == [
        (e.pose, e.status, e.reason, e.mapped) for e in watched
    ]
    assert all(np.array_equal(a.covariance, b.covariance) for a, b in zip(plain, watched, strict=True))


def test_the_patch_lead_in_and_lead_out_come_from_the_typed_config() -> None:
    from icploc.config import LocalizerConfig
    from icploc.localizer import Localizer
    from icploc.outside import attach

    cfg = LocalizerConfig.from_dict({"map": {"patch_lead_in_scans": 7, "patch_lead_out_scans": 3}})
    mon = attach(Localizer(half_known_grid(), cfg, initial_pose=(1.0, 2.0, 0.0)))
    assert (mon.config.lead_in_scans, mon.config.lead_out_scans) == (7, 3)
    # one source of the defaults: the typed config's
    d = LocalizerConfig().map
    assert (OutsideConfig().lead_in_scans, OutsideConfig().lead_out_scans) == (
        d.patch_lead_in_scans,
        d.patch_lead_out_scans,
    )


def test_a_negative_patch_lead_in_is_a_config_error() -> None:
    from icploc.config import LocalizerConfig
    from icploc.errors import ConfigError

    with pytest.raises(ConfigError, match="patch_lead_in_scans"):
        LocalizerConfig.from_dict({"map": {"patch_lead_in_scans": -1}})
