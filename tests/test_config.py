"""Localizer configuration: defaults, YAML round trip, clear errors."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from icploc.config import ConfigError, LocalizerConfig, default_yaml


def test_defaults_round_trip_through_yaml(tmp_path: Path) -> None:
    cfg = LocalizerConfig()
    p = tmp_path / "c.yaml"
    cfg.save(p)
    again = LocalizerConfig.from_yaml(p)
    assert again == cfg
    assert yaml.safe_load(default_yaml()) == cfg.to_dict()


def test_partial_file_overrides_only_given_keys(tmp_path: Path) -> None:
    p = tmp_path / "c.yaml"
    p.write_text(
        "icp:\n  metric: point_to_point\nscan:\n  decimation: 2\n  laser_x: 0.25\n"
        "localizer:\n  initial_pose: [1, 2, 0.5]\nmap:\n  visibility_culling: true\n"
    )
    cfg = LocalizerConfig.from_yaml(p)
    assert cfg.icp.metric == "point_to_point"
    assert cfg.scan.decimation == 2 and cfg.scan.mounting == (0.25, 0.0, 0.0)
    assert cfg.localizer.initial_pose == (1.0, 2.0, 0.5)
    assert cfg.map.visibility_culling is True
    assert cfg.gating == LocalizerConfig().gating
    ic = cfg.icp.to_icp_config()
    assert ic.metric == "point_to_point"


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("icpp:\n  metric: point_to_point\n", "unknown section 'icpp'"),
        ("icp:\n  metrik: point_to_point\n", "unknown key 'metrik'"),
        ("icp:\n  metric: plane\n", "expected one of"),
        ("scan:\n  decimation: 1.5\n", "expected an integer"),
        ("scan:\n  min_range: fast\n", "expected a number"),
        ("map:\n  visibility_culling: 1\n", "expected true/false"),
        ("localizer:\n  initial_pose: [1, 2]\n", "list of 3"),
        ("scan:\n  decimation: 0\n", "scan.decimation must be >= 1"),
        ("gating:\n  min_inlier_ratio: 1.5\n", "gating.min_inlier_ratio"),
        ("icp:\n  max_correspondence_distance: 0.05\n", "must not exceed"),
        ("- just\n- a list\n", "top level must be a mapping"),
        ("icp: [1, 2]\n", "must be a mapping"),
        ("icp: {metric: \n", "invalid YAML"),
    ],
)
def test_bad_files_raise_clear_errors(tmp_path: Path, text: str, needle: str) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as ei:
        LocalizerConfig.from_yaml(p)
    assert needle in str(ei.value)
    assert str(p) in str(ei.value)


def test_missing_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        LocalizerConfig.from_yaml(tmp_path / "nope.yaml")


def test_empty_file_gives_defaults(tmp_path: Path) -> None:
    p = tmp_path / "empty.yaml"
    p.write_text("")
    assert LocalizerConfig.from_yaml(p) == LocalizerConfig()


def test_replace_updates_a_section() -> None:
    cfg = LocalizerConfig().replace(scan={"laser_x": 0.3})
    assert cfg.scan.laser_x == 0.3
    assert LocalizerConfig().scan.laser_x == 0.0
