"""One error root: every error class icploc raises on purpose is an IcplocError, in its
family, and keeps its old built-in base (``except ValueError`` still catches bad input)."""

from __future__ import annotations

from pathlib import Path

import pytest
from icploc.errors import ConfigError, DeviceError, FileFormatError, IcplocError, UsageError


def _classes() -> dict[str, tuple[type, type, type]]:
    """name -> (class, its family, the built-in base it had before)."""
    from icploc import batch, cli, config, live, mcap_export, outputs, state, trajectory
    from icploc.drivers import arcos_protocol, ports, powerbot, recording, sick, sick_protocol
    from icploc.logs import _base, rosbag
    from icploc.maps import errors

    return {
        "MapError": (errors.MapError, FileFormatError, ValueError),
        "LogFormatError": (_base.LogFormatError, FileFormatError, ValueError),
        "TrajectoryFormatError": (trajectory.TrajectoryFormatError, FileFormatError, ValueError),
        "RecordingFormatError": (recording.RecordingFormatError, FileFormatError, ValueError),
        "StateError": (state.StateError, FileFormatError, ValueError),
        "ConfigError": (config.ConfigError, ConfigError, ValueError),
        "TopicError": (rosbag.TopicError, UsageError, ValueError),
        "OutputError": (outputs.OutputError, UsageError, ValueError),
        "UserError": (cli.UserError, UsageError, ValueError),
        "SickError": (sick.SickError, DeviceError, RuntimeError),
        "PowerBotError": (powerbot.PowerBotError, DeviceError, RuntimeError),
        "PortError": (ports.PortError, DeviceError, OSError),
        "SickProtocolError": (sick_protocol.SickProtocolError, DeviceError, ValueError),
        "ArcosProtocolError": (arcos_protocol.ArcosProtocolError, DeviceError, ValueError),
        "McapError": (mcap_export.McapError, IcplocError, RuntimeError),
        "BatchError": (batch.BatchError, IcplocError, RuntimeError),
        "RunError": (live.RunError, IcplocError, RuntimeError),
    }


@pytest.mark.parametrize("name", sorted(_classes()))
def test_every_error_class_is_in_its_family_and_keeps_its_base(name: str) -> None:
    cls, family, old_base = _classes()[name]
    assert (issubclass(cls, family), issubclass(cls, IcplocError), issubclass(cls, old_base)) == (
        True,
        True,
        True,
    )


def test_file_format_error_says_where() -> None:
    e = FileFormatError(Path("a/b.log"), "not a number", 12)
    assert (str(e), e.path, e.line, e.reason) == (
        "a/b.log:12: not a number",
        "a/b.log",
        12,
        "not a number",
    )


def test_log_format_error_is_a_file_format_error_with_path_and_line() -> None:
    from icploc.logs import LogFormatError

    e = LogFormatError("x.clf", "FLASER: zero beams", 3)
    assert (str(e), e.path, e.line) == ("x.clf:3: FLASER: zero beams", "x.clf", 3)


def test_map_error_names_file_and_field() -> None:
    from icploc.maps.errors import MapError

    e = MapError("m.yaml", "resolution", "must be positive")
    assert (str(e), e.path, e.field, e.line) == (
        "m.yaml: field 'resolution': must be positive",
        "m.yaml",
        "resolution",
        None,
    )


def test_map_error_without_a_file() -> None:
    from icploc.maps.errors import MapError

    e = MapError(None, None, "no walls")
    assert (str(e), e.path) == ("<map>: no walls", None)


def test_recording_error_keeps_its_message_form() -> None:
    from icploc.drivers.recording import RecordingFormatError

    e = RecordingFormatError("META record is not a JSON object")
    assert (str(e), e.path, isinstance(e, FileFormatError)) == (
        "META record is not a JSON object",
        None,
        True,
    )


def test_a_bad_trajectory_file_raises_a_file_format_error(tmp_path: Path) -> None:
    from icploc.trajectory import read_tum

    p = tmp_path / "t.tum"
    p.write_text("0 1 2 0 0 0 0 1\n1 x 2 0 0 0 0 1\n")
    with pytest.raises(FileFormatError) as ei:
        read_tum(p)
    assert (ei.value.path, ei.value.line) == (str(p), 2)


def test_a_grid_beyond_the_core_memory_bound_has_its_own_type() -> None:
    import numpy as np
    from icploc._core import GlobalLocalizer, GridTooLargeError, InvalidInputError, MapIndex

    idx = MapIndex(np.array([[0.0, 0.0], [5000.0, 5000.0]]))
    with pytest.raises(GridTooLargeError, match="needs 10000200001 cells") as ei:
        GlobalLocalizer(idx, 0.05)
    assert (isinstance(ei.value, InvalidInputError), isinstance(ei.value, ValueError)) == (
        True,
        True,
    )


def test_global_relocalization_coarsens_on_the_typed_error_only(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import numpy as np
    from icploc import relocalize
    from icploc._core import GridTooLargeError, MapIndex

    tried: list[float] = []

    class Fake:
        def __init__(
            self, index: object, config: relocalize.RelocalizeConfig, **kw: object
        ) -> None:
            tried.append(config.resolution)
            if config.resolution < 0.2:
                raise GridTooLargeError("too many cells")

    monkeypatch.setattr(relocalize, "Relocalizer", Fake)
    g = relocalize.GlobalRelocalization.deferred()
    assert g.ready(MapIndex(np.array([[0.0, 0.0], [10.0, 10.0]])))
    assert tried == pytest.approx([0.05, 0.1, 0.2])


def test_the_core_errors_are_icploc_errors_too() -> None:
    from icploc import _core

    got = [
        issubclass(c, IcplocError)
        for c in (
            _core.IcpError,
            _core.InvalidInputError,
            _core.EmptyMapError,
            _core.GridTooLargeError,
            _core.InvalidConfigError,
        )
    ]
    assert (got, issubclass(_core.InvalidConfigError, ValueError)) == ([True] * 5, True)
