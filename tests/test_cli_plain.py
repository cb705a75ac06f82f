"""``icploc replay ...`` without typer (icploc.cli_args.parse_plain): a plain command line
is read exactly as typer reads it, anything else goes to typer; the command process then
imports neither typer, click, pydantic nor rich, and writes what the typer path writes."""

from __future__ import annotations

import inspect
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, get_origin

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from icploc import cli
from icploc.cli_args import params, parse_plain

VALUES = [
    "x.log", "m.yaml", "0.5", "1", "0", "-1", "-0", "2", "1e-3", ".5", "5.", "1E+2", "nan", "inf",
    "1,2,3", "-1,2,0", "", "-", "--", "abc", " 1", "0x10", "007", "+1", "1_0", "1.0000000000000002",
    "--help", "auto", "scan", "stream", "=", "a=b", "99999999999999999999",
]  # fmt: skip


def _typer_kwargs(func: Callable[..., None], args: list[str]) -> dict[str, Any] | None:
    """The keyword arguments typer calls ``func`` with for ``args`` (None: typer refuses),
    typer converting the values with its own coercion (pydantic), not icploc.cli_app's."""
    import typer
    import typer.core
    from icploc import cli_app
    from icploc.cli_app import callback
    from typer.testing import CliRunner

    if getattr(cli_app, "_TYPER_BUILD", None) is None:
        pytest.skip("this typer has no private coercion layer for icploc.cli_app to compare with")
    got: dict[str, Any] = {}

    def capture(**kw: Any) -> None:
        got.update(kw)

    capture.__signature__ = inspect.signature(func, eval_str=True)  # type: ignore[attr-defined]
    app = typer.Typer(add_completion=False)
    app.command()(callback(capture))
    with pytest.MonkeyPatch.context() as m:
        m.setattr(typer.core, "build_runtime_param", cli_app._TYPER_BUILD)
        r = CliRunner().invoke(app, args)
    return got if r.exit_code == 0 else None


def _typed(kw: dict[str, Any] | None) -> dict[str, tuple[type, Any]] | None:
    return None if kw is None else {k: (type(v), v) for k, v in kw.items()}


def _command_lines(func: Callable[..., None]) -> st.SearchStrategy[list[str]]:
    names = sorted(n for p in params(func) for n in p.flags) + ["--help", "--bogus"]
    token = st.one_of(
        st.sampled_from(names),
        st.sampled_from(VALUES),
        st.builds(lambda o, v: f"{o}={v}", st.sampled_from(names), st.sampled_from(VALUES)),
    )
    return st.lists(token, max_size=9)


def _well_formed(func: Callable[..., None]) -> st.SearchStrategy[list[str]]:
    """Command lines of the command's own shape: a value for each argument, then options
    with values of their type (mostly plain, some not), each at most once, in any order."""
    ps = params(func)
    typed = {
        str: st.sampled_from(["auto", "scan", "stream", "x", "", "1,2,0"]),
        Path: st.sampled_from(["x.log", "m.yaml", "out/t.tum", "a b.csv"]),
        int: st.one_of(st.integers(-3, 100).map(str), st.sampled_from(VALUES)),
        float: st.one_of(st.floats(-10, 10, allow_nan=False).map(repr), st.sampled_from(VALUES)),
    }
    args = [p for p in ps if p.is_arg]
    opts = [p for p in ps if not p.is_arg and p.flags]

    def option(p: Any) -> st.SearchStrategy[list[str]]:
        names = sorted(p.flags)
        if p.base is bool:
            return st.sampled_from(names).map(lambda n: [n])
        value = typed.get(p.base, st.sampled_from(VALUES))
        return st.one_of(
            st.tuples(st.sampled_from(names), value).map(list),
            st.builds(lambda n, v: [f"{n}={v}"], st.sampled_from(names), value),
        )

    head = st.tuples(*(typed.get(p.base, st.just("x")) for p in args)).map(list) if args else st.just([])
    if not opts:
        return head
    required = [p for p in opts if p.default is inspect.Parameter.empty]
    optional = [p for p in opts if p.default is not inspect.Parameter.empty]
    chosen_sets = st.lists(st.sampled_from(optional), unique_by=lambda p: p.name, max_size=6) if optional else st.just([])
    tail = chosen_sets.flatmap(lambda chosen: st.permutations(required + chosen)).flatmap(
        lambda chosen: st.tuples(*(option(p) for p in chosen)).map(lambda parts: [a for q in parts for a in q])
        if chosen
        else st.just([])
    )
    return st.builds(lambda h, t: h + t, head, tail)


@pytest.mark.parametrize("func", [cli.replay, cli.demo, cli.config_check], ids=lambda f: f.__name__)
@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_a_command_line_read_plainly_is_read_as_typer_reads_it(func: Any, data: st.DataObject) -> None:
    args = data.draw(st.one_of(_command_lines(func), _well_formed(func)))
    plain = parse_plain(func, args)
    if plain is not None:  # declining is always allowed: typer then reads it
        assert _typed(plain) == _typed(_typer_kwargs(func, args))


def test_most_well_formed_replay_lines_are_read_plainly() -> None:
    """The comparison above exercises the plain reading: most lines of the command's own
    shape are read plainly (not declined to typer)."""
    lines: list[list[str]] = []

    @settings(max_examples=200, deadline=None, database=None)
    @given(args=_well_formed(cli.replay))
    def draw(args: list[str]) -> None:
        lines.append(args)

    draw()
    read = sum(parse_plain(cli.replay, a) is not None for a in lines)
    assert read >= len(lines) // 2


def test_an_existing_unreadable_path_is_left_to_typer(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """typer refuses an existing path it cannot read (click.Path readable=True) with its
    usage error; the plain reading declines it rather than taking it."""
    log = tmp_path / "x.log"
    log.write_text("")
    args = [str(log), "--map", "m.yaml"]
    assert parse_plain(cli.replay, args) is not None
    monkeypatch.setattr("icploc.cli_args.os.access", lambda path, mode: str(path) != str(log))
    assert parse_plain(cli.replay, args) is None


def test_the_typer_app_falls_back_to_typers_own_coercion_if_its_helpers_change(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A typer whose private helpers changed signature: icploc.cli_app's plain conversion
    gives way to typer's own coercion instead of failing the command."""
    from icploc import cli_app

    if getattr(cli_app, "_TYPER_BUILD", None) is None:
        pytest.skip("this typer has no private coercion layer")

    def changed(*a: Any, **k: Any) -> Any:
        raise TypeError("coerce_cli_path() got an unexpected keyword argument 'path_type'")

    monkeypatch.setattr(cli_app, "_plain_value", changed)
    for ann, bounds, value in [(int, (0, None), "7"), (Path, (None, None), "a.log"), (float, (0.0, 1.0), "2")]:
        ours = _coerce(cli_app._build_runtime_param, ann, bounds, value)
        assert ours == _coerce(cli_app._TYPER_BUILD, ann, bounds, value)
    assert _coerce(cli_app._build_runtime_param, int, (0, None), "7") == ("value", (int, 7))


class _Param:
    multiple, nargs = False, 1


_ANNOTATIONS = [str, Path, int, float, bool, list[str], list[Path]]
_BOUNDS = [(None, None), (0.0, 1.0), (0, None), (None, 5)]
_RAW = st.one_of(
    st.sampled_from(VALUES),
    st.text(alphabet="0123456789.-+eE x_", max_size=8),
    st.sampled_from([0, 1, -3, 7, 0.5, 2.0, float("nan"), True, False, Path("p"), b"b"]),
)


def _coerce(build: Any, ann: Any, bounds: tuple[Any, Any], value: Any) -> tuple[str, Any]:
    from typer._coercion import resolve_type_descriptor
    from typer.models import OptionInfo

    info = OptionInfo(min=bounds[0], max=bounds[1])
    param = _Param()
    if get_origin(ann) is list:
        param.multiple = True
        value = value if isinstance(value, list) else [value]
    try:
        got = build(resolve_type_descriptor(ann, info)).coerce(value, param=param, ctx=None)
    except Exception as e:  # noqa: BLE001 - the same refusal is what is compared
        return "refused", (type(e).__name__, getattr(e, "message", str(e)))
    return "value", (type(got), got if not isinstance(got, float) or got == got else "nan")


@settings(max_examples=600, deadline=None)
@given(
    ann=st.sampled_from(_ANNOTATIONS),
    bounds=st.sampled_from(_BOUNDS),
    value=st.one_of(_RAW, st.lists(_RAW, max_size=3)),
)
def test_the_typer_apps_value_coercion_is_typers_own(ann: Any, bounds: Any, value: Any) -> None:
    """icploc.cli_app converts plain values without pydantic and hands the rest to typer's
    own coercion: the same value of the same type, or the same refusal."""
    from icploc import cli_app

    if getattr(cli_app, "_TYPER_BUILD", None) is None:
        pytest.skip("this typer has no private coercion layer")
    if ann in (str, Path, bool, list[str], list[Path]):
        bounds = (None, None)
    ours = _coerce(cli_app._build_runtime_param, ann, bounds, value)
    assert ours == _coerce(cli_app._TYPER_BUILD, ann, bounds, value)


def test_help_through_typer_imports_no_pydantic() -> None:
    code = (
        "import sys, icploc.cli as c\n"
        "sys.argv = ['icploc', 'replay', '--help']\n"
        "try:\n    c.main()\nexcept SystemExit:\n    pass\n"
        "print('pydantic' in sys.modules, file=sys.stderr)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert (out.stderr.strip().splitlines()[-1], "--initial-pose" in out.stdout) == ("False", True)


@pytest.mark.parametrize(
    "args",
    [
        ["x.log", "--map", "m.yaml"],
        ["--map=m.yaml", "x.log", "--initial-pose", "-1,2,0", "--no-progress", "--max-lost", "1"],
        ["x.log", "--map", "m.yaml", "--strict", "--no-cache", "--out", "t.tum", "--odometry", "scan"],
    ],
)
def test_the_usual_replay_command_lines_are_read_plainly(args: list[str]) -> None:
    plain = parse_plain(cli.replay, args)
    assert plain is not None and _typed(plain) == _typed(_typer_kwargs(cli.replay, args))


@pytest.mark.parametrize(
    "args",
    [
        ["x.log", "--map", "m.yaml", "--help"],
        ["x.log", "--map", "m.yaml", "--max-lost", "2"],  # out of range: typer's message
        ["x.log"],  # --map missing
        ["x.log", "--map", "m.yaml", "--map", "n.yaml"],
        ["x.log", "y.log", "--map", "m.yaml"],
        ["x.log", "--map", "m.yaml", "--strict=1"],
        ["x.log", "--map", "m.yaml", "--bogus"],
        ["--", "x.log", "--map", "m.yaml"],
    ],
)
def test_what_is_not_plain_goes_to_typer(args: list[str]) -> None:
    assert parse_plain(cli.replay, args) is None


@pytest.fixture(scope="module")
def small_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    from icploc import sim as worlds
    from icploc.logs import write_carmen
    from icploc.maps import Map

    d = tmp_path_factory.mktemp("plain")
    w = worlds.lab(people=1)
    frames = list(worlds.simulate(w, worlds.lab_random_walk(5.0, seed=2), seed=1, max_frames=40))
    log = d / "run.log"
    scans, odometry = [f.scan for f in frames], [f.odometry for f in frames]
    write_carmen(log, scans, odometry, scan_odometry=[o.pose for o in odometry])
    return {"log": log, "map": Map.from_lines(w.lines).to_ros(d / "m.yaml", 0.05), "dir": d}


def _command(*args: str) -> subprocess.CompletedProcess[str]:
    code = (
        "import sys, icploc.cli as c\n"
        f"sys.argv = ['icploc', *{list(args)!r}]\n"
        "try:\n    c.main()\n"
        "finally:\n"
        "    heavy = ('typer', 'click', 'pydantic', 'rich', 'yaml', 'icploc.cli_app')\n"
        "    print('imported:', *(m for m in heavy if m in sys.modules), file=sys.stderr)\n"
    )
    env = {**os.environ, "ICPLOC_NO_CACHE": "1"}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)


def test_a_plain_replay_imports_no_cli_framework_and_writes_what_typer_writes(
    small_run: dict[str, Path], tmp_path: Path
) -> None:
    from icploc.cli import app
    from typer.testing import CliRunner

    plain, typed = tmp_path / "plain.tum", tmp_path / "typer.tum"
    common = [str(small_run["log"]), "--map", str(small_run["map"]), "--initial-pose", "0,0,0"]
    r = _command("replay", *common, "--out", str(plain), "--no-progress")
    t = CliRunner().invoke(app, ["replay", *common, "--out", str(typed), "--no-progress"])
    assert (r.returncode, r.stderr.strip().splitlines()[-1]) == (0, "imported:"), r.stderr
    assert r.stdout.splitlines()[1:-1] == t.output.splitlines()[1:-1]  # the times differ
    a, b = (np.loadtxt(p) for p in (plain, typed))
    assert np.array_equal(a, b)


def test_a_plain_replay_with_a_bad_option_value_is_reported_by_typer(small_run: dict[str, Path]) -> None:
    r = _command("replay", str(small_run["log"]), "--map", str(small_run["map"]), "--initial-pose", "1,2")
    assert (r.returncode, "X,Y,THETA" in r.stderr, "Usage:" in r.stderr) == (2, True, True)


def test_a_plain_replay_of_a_missing_log_is_one_error_line(tmp_path: Path) -> None:
    missing = tmp_path / "missing.log"
    r = _command("replay", str(missing), "--map", str(tmp_path / "m.yaml"))
    assert (r.returncode, r.stderr.splitlines()[0]) == (1, f"error: {missing}: no such log file")
