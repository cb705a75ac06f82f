"""The defaults' fast path: ``Section()`` / ``LocalizerConfig()`` without values skip the
validator (built lazily), and give exactly what the validated construction gives."""

from __future__ import annotations

import subprocess
import sys

import pytest
from icploc.config import _SECTIONS, ConfigError, LocalizerConfig, Section


@pytest.mark.parametrize("section", _SECTIONS, ids=lambda s: s.section)
def test_a_default_section_equals_its_validated_defaults(section: type[Section]) -> None:
    fast = section()
    checked = section.model_validate({})  # the validator: field and model checks
    assert (fast.__dict__, fast.model_fields_set) == (checked.__dict__, checked.model_fields_set)


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
