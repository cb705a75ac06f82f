"""The outside-the-map state is the default (config ``outside.enabled``): a Localizer built
with the default config, fed by ``icploc.localizer.run`` as the README shows, coasts where
the scan is outside the map instead of matching it against the wrong walls.

On the simulated building whose map lacks a wing (tests/partial_world.py), seed 24, the
same run with the state turned off reported 347 scans ``tracking`` 17-26 m off: lost at the
door, its dead reckoning 8 cm off, the global recovery locked the wing's scans onto the
hall's south-west corner, where they verify (hit share 0.80 against the usual 0.78, no
beam on unmapped space at that pose)."""

from __future__ import annotations

import numpy as np
import pytest
from icploc.config import LocalizerConfig
from icploc.errors import ConfigError
from partial_world import errors, half_known_grid, partial_run

SEED = 24


def test_the_default_config_turns_the_outside_state_on() -> None:
    from icploc.localizer import Localizer
    from icploc.outside import OutsideMonitor

    assert LocalizerConfig().outside.enabled is True
    loc = Localizer(half_known_grid(), initial_pose=(1.0, 2.0, 0.0))
    assert isinstance(loc.outside, OutsideMonitor)


def test_a_grid_with_every_cell_known_gets_no_monitor_by_default_but_on_request() -> None:
    # such a grid does not say where the map was not made (knows_unknown: unknown cells)
    from icploc.localizer import Localizer
    from icploc.outside import OutsideMonitor, attach, knows_unknown

    full, half = half_known_grid(unknown=False), half_known_grid()
    assert [knows_unknown(full), knows_unknown(half)] == [False, True]
    loc = Localizer(full, initial_pose=(1.0, 2.0, 0.0))
    assert loc.outside is None
    assert isinstance(attach(loc), OutsideMonitor)


def test_a_map_of_lines_gets_no_monitor_by_default_but_on_request() -> None:
    # a map of lines does not say where it ends (the glass lab's beams end beyond it)
    from icploc.localizer import Localizer
    from icploc.maps import Map
    from icploc.outside import OutsideMonitor, attach

    m = Map.from_lines(np.array([[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 4.0]]))
    loc = Localizer(m, initial_pose=(1.0, 1.0, 0.0))
    assert loc.outside is None
    assert isinstance(attach(loc), OutsideMonitor)


def test_outside_enabled_false_leaves_the_localizer_without_a_monitor() -> None:
    from icploc.localizer import Localizer

    cfg = LocalizerConfig.from_dict({"outside": {"enabled": False}})
    assert Localizer(half_known_grid(), cfg, initial_pose=(1.0, 2.0, 0.0)).outside is None


def test_outside_enabled_round_trips_through_yaml(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p = tmp_path / "c.yaml"
    LocalizerConfig.from_dict({"outside": {"enabled": False}}).save(p)
    assert LocalizerConfig.from_yaml(p).outside.enabled is False


def test_outside_enabled_must_be_a_bool() -> None:
    with pytest.raises(ConfigError, match=r"outside\.enabled"):
        LocalizerConfig.from_dict({"outside": {"enabled": "yes"}})


def test_a_stretch_needs_at_least_one_scan_in_a_row() -> None:
    from icploc.outside import OutsideConfig

    assert OutsideConfig().enter_scans == 2
    with pytest.raises(ValueError, match="enter_scans"):
        OutsideConfig(enter_scans=0).validate()


def test_a_point_map_kilometres_wide_gets_a_bounded_mask() -> None:
    from icploc.outside import MappedArea, OutsideConfig

    class _Index:  # two walls 3 km apart
        points = np.array([[0.0, 0.0], [0.0, 1.0], [3000.0, 3000.0], [3000.0, 3001.0]])

    cfg = OutsideConfig(max_mask_cells=1_000_000)
    area = MappedArea.of(object(), _Index(), cfg)
    assert area.known.size <= 1.1 * cfg.max_mask_cells
    # still mapped next to a wall, unmapped half way between them
    assert area.unmapped(np.array([[0.2, 0.5], [1500.0, 1500.0]])).tolist() == [False, True]


def test_the_default_api_reports_no_tracking_far_off_and_says_where_the_map_is_missing() -> None:
    # ~9 s on a loaded machine: in the default suite
    from icploc.localizer import Localizer, run

    r, m = partial_run(SEED)
    loc = Localizer(m, initial_pose=tuple(r.truth[0]))  # the default config, nothing attached
    ests = run(loc, r.items)
    err = errors(r, ests)
    tracking = np.array([e.status.value == "tracking" for e in ests])
    mapped = np.array([e.mapped for e in ests])
    deep = r.truth[:, 0] > 21.5  # in the wing's room, away from the corridor
    assert int(np.sum(tracking & (err > 0.5))) == 0
    assert float(np.mean(~mapped[deep])) >= 0.95
    assert {e.reason for e in ests if not e.mapped} == {"outside_map"}
    assert [(s.closed, s.outside_scans > 500) for s in loc.outside.stretches] == [(True, True)]
