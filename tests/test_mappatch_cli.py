"""``icploc replay ... --map-patch PATCH --confident-only``: the CLI's way to the Python
API's ``confident_only`` (icploc.mappatch.write_patch)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from icploc import sim as worlds
from icploc.cli import app
from icploc.logs import write_carmen
from icploc.maps import Map
from typer.testing import CliRunner

runner = CliRunner()


@pytest.fixture(scope="module")
def lab_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("patchcli")
    w = worlds.lab(people=0)
    frames = list(worlds.simulate(w, worlds.lab_random_walk(5.0, seed=2), seed=1, max_frames=40))
    log = d / "run.log.gz"
    write_carmen(
        log, [f.scan for f in frames], [f.odometry for f in frames],
        scan_odometry=[f.odometry.pose for f in frames],
    )  # fmt: skip
    return {"log": log, "map": Map.from_lines(w.lines).to_ros(d / "m.yaml", 0.05)}


@pytest.mark.parametrize("flag", [True, False])
def test_confident_only_reaches_the_patch_writer(
    lab_run: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, flag: bool
) -> None:
    from icploc import mappatch

    seen: list[Any] = []
    real = mappatch.write_patch

    def spy(*args: Any, **kwargs: Any) -> Any:
        seen.append(kwargs.get("confident_only"))
        return real(*args, **kwargs)

    monkeypatch.setattr(mappatch, "write_patch", spy)
    args = [
        "replay", str(lab_run["log"]), "--map", str(lab_run["map"]), "--no-progress",
        "--initial-pose", "0,0,0", "--map-patch", str(tmp_path / "patch.yaml"),
    ]  # fmt: skip
    r = runner.invoke(app, [*args, "--confident-only"] if flag else args)
    assert r.exit_code == 0, r.output
    assert seen == [flag]


def test_confident_only_without_a_patch_is_a_usage_error(lab_run: dict[str, Path]) -> None:
    r = runner.invoke(
        app,
        ["replay", str(lab_run["log"]), "--map", str(lab_run["map"]), "--no-progress", "--confident-only"],
    )
    assert r.exit_code == 2
    assert "--confident-only" in r.output and "needs --map-patch" in r.output
