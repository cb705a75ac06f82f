"""Real laser data (../shared/data): the localizer on held-out scans of corrected logs.

Skipped when ../shared is absent. The map is built from the odd-numbered scans at their
corrected poses, the even-numbered ones are localized with synthesised drifting odometry
(benches/eval_real.py does this for every log and reports the figures).
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"

pytestmark = pytest.mark.shared_data


def _eval_module():  # noqa: ANN202
    spec = importlib.util.spec_from_file_location("eval_real", ROOT / "benches" / "eval_real.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.skipif(not DATA.exists(), reason="../shared/data is absent")
@pytest.mark.parametrize(
    "log",
    [
        "radish_corrected_logs/seattle-corrected.log.gz",
        "radish_corrected_logs/orebro-corrected.log.gz",  # all stamps 0 in the file
        "freiburg_course/csail.log",  # ROBOTLASER1, real stamps
    ],
)
def test_localizes_held_out_scans_of_a_real_log(log: str) -> None:
    ev = _eval_module()
    r = ev.evaluate(DATA / log, "alternate", seed=0)
    assert "error" not in r, r
    assert r["nan_poses"] == 0
    assert r["status"].get("lost", 0) == 0
    assert r["ate_rmse_m"] < 0.05, r
    assert r["ate_max_m"] < 0.15, r
    # the synthesised odometry really drifts (tens of metres): the map did the work
    assert r["odometry_ate_rmse_m"] > 5.0
    assert math.isfinite(r["localize_scans_per_s"])
