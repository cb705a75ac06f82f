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
        ("scan:\n  decimation: 0\n", "scan.decimation: must be >= 1, got 0"),
        ("gating:\n  min_inlier_ratio: 1.5\n", "gating.min_inlier_ratio"),
        (
            "icp:\n  max_correspondence_distance: 0.05\n",
            "icp.min_correspondence_distance: must not exceed",
        ),
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


# ----------------------------------------------------------------------------- issue 14


@pytest.mark.parametrize(
    ("section", "kw", "needle"),
    [
        ("icp", {"robust_scale": 0.0}, "icp.robust_scale"),
        ("icp", {"min_inliers": -5}, "icp.min_inliers"),
        ("icp", {"max_iterations": -1}, "icp.max_iterations"),
        ("icp", {"max_iterations": 2.5}, "icp.max_iterations: expected an integer"),
        ("scan", {"laser_x": float("inf")}, "scan.laser_x"),
        ("scan", {"decimation": "2"}, "scan.decimation: expected an integer"),
        ("localizer", {"recover_after": True}, "localizer.recover_after: expected an integer"),
        ("gating", {"max_translation_jump": float("nan")}, "gating.max_translation_jump"),
        ("map", {"spacing": 1e-6}, "map.spacing: must be >= 0.001"),
        ("localizer", {"calibration_max_skew": -0.01}, "localizer.calibration_max_skew: must be >= 0"),
        ("localizer", {"noise_gain_window": 0}, "localizer.noise_gain_window: must be >= 1"),
        (
            "localizer",
            {"noise_gain_window": 4, "noise_gain_min_samples": 5},
            "noise_gain_min_samples: must not exceed noise_gain_window",
        ),
    ],
)
def test_sections_are_validated_at_construction_naming_the_field(
    section: str, kw: dict, needle: str
) -> None:
    from icploc import config as c

    cls = {
        "icp": c.IcpSection,
        "scan": c.ScanSection,
        "gating": c.GatingSection,
        "localizer": c.LocalizerSection,
        "map": c.MapSection,
    }[section]
    with pytest.raises(ConfigError, match=needle):
        cls(**kw)


def test_replace_validates_too() -> None:
    with pytest.raises(ConfigError, match="icp.robust_scale"):
        LocalizerConfig().icp.replace(robust_scale=-1.0)


def test_assignment_validates_too() -> None:
    cfg = LocalizerConfig()
    with pytest.raises(ConfigError, match=r"scan\.decimation: must be >= 1, got 0"):
        cfg.scan.decimation = 0


def test_wrong_section_type_is_an_error() -> None:
    with pytest.raises(ConfigError, match="icp: expected a IcpSection"):
        LocalizerConfig(icp={"metric": "point_to_point"})  # type: ignore[arg-type]


def test_icp_section_checked_by_the_core(monkeypatch: pytest.MonkeyPatch) -> None:
    """The Rust IcpConfig's own validation runs at construction (not a copy of it)."""
    from icploc import _core
    from icploc.config import IcpSection

    class Refusing:
        def __init__(self, **kw: object) -> None:
            raise _core.InvalidConfigError("invalid config: mse_change = 7: refused by the core")

    monkeypatch.setattr(_core, "IcpConfig", Refusing)
    with pytest.raises(ConfigError, match="icp.mse_change: refused by the core, got 7"):
        IcpSection()


def test_duplicated_yaml_key_is_an_error(tmp_path: Path) -> None:
    p = tmp_path / "d.yaml"
    p.write_text("scan:\n  laser_x: 0.1\n  laser_x: 0.2\n")
    with pytest.raises(
        ConfigError, match=r"d\.yaml:3: duplicate key 'laser_x' \(first at line 2\)"
    ):
        LocalizerConfig.from_yaml(p)


def test_duplicated_yaml_section_is_an_error(tmp_path: Path) -> None:
    p = tmp_path / "d.yaml"
    p.write_text("scan:\n  laser_x: 0.1\nicp: {}\nscan:\n  laser_y: 0.2\n")
    with pytest.raises(ConfigError, match=r"d\.yaml:4: duplicate key 'scan'"):
        LocalizerConfig.from_yaml(p)


def test_non_utf8_config_names_file_and_line(tmp_path: Path) -> None:
    p = tmp_path / "l1.yaml"
    p.write_bytes(b"# r\xe9glages\nscan:\n  laser_x: 0.1\n")
    with pytest.raises(ConfigError, match=r"l1\.yaml:1: not UTF-8 text \(byte 0xe9"):
        LocalizerConfig.from_yaml(p)


def test_huge_file_is_not_parsed_as_a_config(tmp_path: Path) -> None:
    p = tmp_path / "big.yaml"
    p.write_bytes(b"#" * (2 << 20))
    with pytest.raises(ConfigError, match="not a config file"):
        LocalizerConfig.from_yaml(p)


# ----------------------------------------------------------------------------- issue 15


def test_error_names_the_file_and_the_field(tmp_path: Path) -> None:
    p = tmp_path / "config.yaml"
    p.write_text("localizer:\n  lost_sigma_xy: -1\n")
    with pytest.raises(ConfigError) as ei:
        LocalizerConfig.from_yaml(p)
    assert (str(ei.value), ei.value.path, ei.value.field) == (
        f"{p}: localizer.lost_sigma_xy: must be > 0, got -1",
        str(p),
        "localizer.lost_sigma_xy",
    )


@pytest.mark.parametrize(
    ("text", "section", "key", "value"),
    [
        ("relocalize:\n  confirm_scans: 5\n", "relocalize", "confirm_scans", 5),
        ("recovery:\n  headings: [-0.2, 0.2]\n", "recovery", "headings", (-0.2, 0.2)),
        ("kidnap:\n  doubt_scans: 12\n", "kidnap", "doubt_scans", 12),
    ],
)
def test_relocalization_and_lost_detection_settings_come_from_the_file(
    tmp_path: Path, text: str, section: str, key: str, value: object
) -> None:
    p = tmp_path / "c.yaml"
    p.write_text(text)
    assert getattr(getattr(LocalizerConfig.from_yaml(p), section), key) == value


@pytest.mark.parametrize(
    ("section", "kw", "needle"),
    [
        ("relocalize", {"confirm_scans": 0}, "relocalize.confirm_scans: must be >= 1, got 0"),
        ("relocalize", {"dominance": 1.0}, "relocalize.dominance: must be < 1"),
        ("recovery", {"min_radius": 3.0}, "recovery.min_radius: must not exceed max_radius"),
        ("kidnap", {"doubt": 1.5}, "kidnap.doubt: must be <= 1"),
    ],
)
def test_new_sections_are_validated(section: str, kw: dict, needle: str) -> None:
    with pytest.raises(ConfigError, match=needle):
        LocalizerConfig().replace(**{section: kw})


def test_defaults_yaml_carries_descriptions_units_and_ranges() -> None:
    lines = default_yaml().splitlines()
    i = lines.index("  max_translation_jump: 1.5")
    assert lines[i - 1] == "  # hard cap on one correction's translation [m, > 0]"


def test_every_numeric_key_in_the_defaults_has_a_comment() -> None:
    lines = default_yaml().splitlines()
    keys = [i for i, ln in enumerate(lines) if ln.startswith("  ") and not ln.startswith("  #")]
    assert [lines[i] for i in keys if not lines[i - 1].startswith("  #")] == []


def test_icp_defaults_are_the_cores() -> None:
    from icploc._core import IcpConfig

    core = IcpConfig().to_dict()
    ours = LocalizerConfig().icp.to_dict()
    assert {k: ours[k] for k in ours if k in core} == {k: core[k] for k in ours if k in core}


def test_the_relocalization_components_read_their_settings_from_the_config() -> None:
    from icploc.kidnap import KidnapTrigger
    from icploc.recovery import LocalRecovery
    from icploc.relocalize import GlobalRelocalization

    cfg = LocalizerConfig().replace(
        kidnap={"doubt_scans": 12},
        recovery={"max_radius": 1.5},
        localizer={"recover_after": 4},
        relocalize={"lost_margin": 0.2},
    )
    got = GlobalRelocalization.deferred(config=cfg)
    trigger = KidnapTrigger.from_config(cfg.kidnap)
    local = LocalRecovery.from_config(cfg)
    assert (trigger.doubt_scans, local.max_radius, local.confirm, got.settings.lost_margin) == (
        12,
        1.5,
        4,
        0.2,
    )
    assert got.local.max_radius == 1.5


def test_global_search_defaults_are_the_cores() -> None:
    from icploc._core import global_defaults

    assert LocalizerConfig().global_search.to_dict() == global_defaults()


def test_global_search_settings_reach_the_global_localizer() -> None:
    import numpy as np
    from icploc._core import MapIndex
    from icploc.relocalize import GlobalRelocalization

    cfg = LocalizerConfig().replace(global_search={"max_candidates": 5, "ambiguity_margin": 0.2})
    g = GlobalRelocalization.deferred(config=cfg)
    x = np.linspace(0.0, 4.0, 81)
    walls = np.vstack([np.column_stack([x, 0 * x]), np.column_stack([x, 0 * x + 3.0])])
    assert g.ready(MapIndex(walls))
    rel = g.relocalizer
    assert (rel.search_cap, rel.glob.ambiguity_margin) == (5, 0.2)
