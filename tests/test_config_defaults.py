"""The defaults' fast path: ``Section()`` / ``LocalizerConfig()`` without values skip the
validator (its pydantic twin, built lazily: icploc.lazy_model), and give exactly what the
validated construction gives."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys

import pytest
from icploc.config import _SECTIONS, ConfigError, LocalizerConfig, Section


@pytest.mark.parametrize("section", _SECTIONS, ids=lambda s: s.section)
def test_a_default_section_equals_its_validated_defaults(section: type[Section]) -> None:
    fast = section()
    checked = section.model_validate({})  # the validator: field and model checks
    assert (type(fast), fast.__dict__) == (type(checked), checked.__dict__)


def test_default_config_equals_the_validated_one() -> None:
    checked = LocalizerConfig.model_validate({s.section: s.model_validate({}) for s in _SECTIONS})
    assert LocalizerConfig().to_dict() == checked.to_dict()


def test_a_default_config_still_validates_assignment() -> None:
    cfg = LocalizerConfig()
    with pytest.raises(ConfigError, match=r"localizer\.lost_sigma_xy: must be > 0, got -1"):
        cfg.localizer.lost_sigma_xy = -1.0


def test_default_sections_are_separate_objects() -> None:
    a, b = LocalizerConfig(), LocalizerConfig()
    a.recovery.keep = 9
    assert b.recovery.keep == LocalizerConfig().recovery.keep != 9


def test_importing_the_config_and_using_its_defaults_imports_no_yaml() -> None:
    code = (
        "import sys, icploc.config as c; c.LocalizerConfig().icp.to_icp_config(); "
        "print('yaml' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_icp_config_with_changes_is_the_replaced_sections() -> None:
    sec = LocalizerConfig().icp
    changes = {"window_search": False, "robust_scale": 0.08, "max_correspondence_distance": 0.9}
    got, want = sec.to_icp_config(**changes), sec.replace(**changes).to_icp_config()
    names = [n for n in dir(want) if not n.startswith("_") and not callable(getattr(want, n))]
    assert {n: getattr(got, n) for n in names} == {n: getattr(want, n) for n in names}


def test_icp_config_refuses_an_outer_loop_key() -> None:
    with pytest.raises(TypeError, match="not a setting of the core: correspondence_sigmas"):
        LocalizerConfig().icp.to_icp_config(correspondence_sigmas=2.0)


def test_a_default_replay_imports_no_pydantic() -> None:
    """A replay with the defaults never pays for importing pydantic and building a model's
    validator (~70 ms of CPU)."""
    code = (
        "import sys, numpy as np, icploc.replay\n"
        "from icploc.localizer import Localizer\n"
        "loc = Localizer(np.c_[np.linspace(0, 5, 200), np.zeros(200)])\n"
        "print(sorted(m for m in ('pydantic', 'pydantic_core') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_validated_section_is_the_same_class() -> None:
    got = LocalizerConfig.from_dict({"icp": {"max_iterations": 7}})
    assert (type(got.icp), got.icp.max_iterations, type(got.scan)) == (
        type(LocalizerConfig().icp),
        7,
        type(LocalizerConfig().scan),
    )


def test_a_field_is_no_class_attribute() -> None:
    """As in a pydantic model: the values live on the instances only."""
    assert not hasattr(LocalizerConfig, "icp")


def test_a_config_pickles_to_an_equal_one() -> None:
    import pickle

    cfg = LocalizerConfig.from_dict({"localizer": {"lost_sigma_xy": 3.0}})
    assert pickle.loads(pickle.dumps(cfg)) == cfg


# -- the classes whose defaults are settings: one source, the config model ---------------------

#: (module, class, attribute) -> the localizer: setting its default comes from (and how)
_FROM_CONFIG = {
    ("icploc.calibration", "OdometryCalibration", "memory"): ("calibration_memory", "x"),
    ("icploc.calibration", "OdometryCalibration", "max_scale"): ("calibration_max_scale", "x"),
    ("icploc.calibration", "OdometryCalibration", "max_turn_scale"): ("calibration_max_turn_scale", "x"),
    ("icploc.calibration", "OdometryCalibration", "max_drift"): ("calibration_max_drift_deg", "math.radians(x)"),
    ("icploc.calibration", "OdometryCalibration", "max_skew"): ("calibration_max_skew", "x"),
    ("icploc.calibration", "OdometryCalibration", "enabled"): ("calibrate_odometry", "x"),
    ("icploc.motion", "NoiseGain", "max_gain"): ("noise_gain_max", "x"),
    ("icploc.motion", "NoiseGain", "window"): ("noise_gain_window", "x"),
    ("icploc.motion", "NoiseGain", "min_samples"): ("noise_gain_min_samples", "x"),
}


@pytest.mark.parametrize("name", ["OdometryCalibration", "NoiseGain"])
def test_a_default_object_is_the_one_the_default_config_makes(name: str) -> None:
    """What the localizer builds from the default config (``from_config``) is what the
    class's own defaults give: no default of its differs from the config's."""
    from icploc.calibration import OdometryCalibration
    from icploc.config import LocalizerSection
    from icploc.motion import NoiseGain

    cls = {"OdometryCalibration": OdometryCalibration, "NoiseGain": NoiseGain}[name]
    assert cls() == cls.from_config(LocalizerSection())


def test_the_class_defaults_are_read_from_the_config_model() -> None:
    """One source, not two equal literals: with the config model's defaults changed before
    the classes are imported (a fresh interpreter), the classes' defaults change with them."""
    code = (
        "import json, math, importlib\n"
        "import icploc.config as c\n"
        f"table = {_FROM_CONFIG!r}\n"
        "F = c.LocalizerSection._fields\n"
        "for setting, _ in table.values():\n"
        "    d = F[setting].default\n"
        "    F[setting].default = (not d) if isinstance(d, bool) else d * 2 + 1\n"
        "out = []\n"
        "for (mod, cls, attr), (setting, how) in table.items():\n"
        "    got = getattr(getattr(importlib.import_module(mod), cls)(), attr)\n"
        "    want = eval(how, {'math': math, 'x': F[setting].default})\n"
        "    out.append([mod, cls, attr, got, want])\n"
        "print(json.dumps(out))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    rows = json.loads(out.stdout)
    assert len(rows) == len(_FROM_CONFIG)
    assert [r for r in rows if r[3] != r[4]] == []
    # and the change was real: each class default there differs from the one here
    here = [getattr(getattr(importlib.import_module(mod), cls)(), attr) for mod, cls, attr in _FROM_CONFIG]
    assert [r[:3] for r, h in zip(rows, here, strict=True) if r[3] == h] == []
