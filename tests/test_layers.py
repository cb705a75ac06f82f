"""The package's layers: basics -> formats and devices -> localization -> applications -> CLI.

Every module of ``python/icploc`` has one layer in :data:`LAYERS`; its imports (at module
level, inside functions and under ``TYPE_CHECKING``) are read with :mod:`ast`, without
importing anything. A module may import from its own layer or a lower one, never from a
higher one, and the module-level imports have no circle. docs/ARCHITECTURE.md describes
the layers.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "icploc"

BASICS, FORMATS, LOCALIZATION, APPLICATIONS, CLI = range(5)
LAYER_NAMES = ("basics", "formats and devices", "localization", "applications", "CLI")

#: the layer of every module (the binding ``icploc._core`` is Rust: it imports nothing here)
LAYERS: dict[str, int] = {
    # basics: plain types, the error root, settings, the binding
    "icploc._core": BASICS,
    "icploc.errors": BASICS,
    "icploc.se2": BASICS,
    "icploc.messages": BASICS,
    "icploc.status": BASICS,
    "icploc.types": BASICS,  # deprecated alias of icploc.messages
    "icploc.clock": BASICS,
    "icploc.median": BASICS,
    "icploc.outputs": BASICS,
    "icploc.laser_mounts": BASICS,
    "icploc.lazy_model": BASICS,
    "icploc.flat_yaml": BASICS,
    "icploc.config": BASICS,
    # formats and devices: map and log files, trajectories, serial devices, the simulator
    "icploc.trajectory": FORMATS,
    "icploc.foxglove_pb": FORMATS,
    "icploc.maps": FORMATS,
    "icploc.maps.build": FORMATS,
    "icploc.maps.cache": FORMATS,
    "icploc.maps.dxf": FORMATS,
    "icploc.maps.errors": FORMATS,
    "icploc.maps.formats": FORMATS,
    "icploc.maps.geojson": FORMATS,
    "icploc.maps.linefit": FORMATS,
    "icploc.maps.map": FORMATS,
    "icploc.maps.merge": FORMATS,
    "icploc.maps.plot": FORMATS,
    "icploc.maps.points": FORMATS,
    "icploc.maps.prepared": FORMATS,
    "icploc.maps.raster": FORMATS,
    "icploc.maps.ros": FORMATS,
    "icploc.maps.sampling": FORMATS,
    "icploc.maps.visibility": FORMATS,
    "icploc.logs": FORMATS,
    "icploc.logs._base": FORMATS,
    "icploc.logs.carmen": FORMATS,
    "icploc.logs.recorded": FORMATS,
    "icploc.logs.rosbag": FORMATS,
    "icploc.drivers": FORMATS,
    "icploc.drivers._queues": FORMATS,
    "icploc.drivers._link": FORMATS,
    "icploc.drivers.arcos_protocol": FORMATS,
    "icploc.drivers.byteclock": FORMATS,
    "icploc.drivers.ports": FORMATS,
    "icploc.drivers.powerbot": FORMATS,
    "icploc.drivers.recording": FORMATS,
    "icploc.drivers.sick": FORMATS,
    "icploc.drivers.sick_protocol": FORMATS,
    "icploc.sim": FORMATS,
    "icploc.sim.world": FORMATS,
    "icploc.sim.robot": FORMATS,
    "icploc.sim.kinematic": FORMATS,
    "icploc.sim.pursuit": FORMATS,
    "icploc.sim.scenes": FORMATS,
    "icploc.sim.device": FORMATS,
    "icploc.sim.pty": FORMATS,
    "icploc.sim.pls_device": FORMATS,
    "icploc.sim.powerbot_device": FORMATS,
    "icploc.sim.session": FORMATS,
    # localization: scans and odometry in, a pose and a status out
    "icploc.scanprep": LOCALIZATION,
    "icploc.motion": LOCALIZATION,
    "icploc.fusion": LOCALIZATION,
    "icploc.calibration": LOCALIZATION,
    "icploc.fitcheck": LOCALIZATION,
    "icploc.kidnap": LOCALIZATION,
    "icploc.recovery": LOCALIZATION,
    "icploc.relocalize": LOCALIZATION,
    "icploc.localizer": LOCALIZATION,
    "icploc.state": LOCALIZATION,
    "icploc.outside": LOCALIZATION,
    "icploc.mappatch": LOCALIZATION,
    "icploc.startrefine": LOCALIZATION,
    "icploc.multilaser": LOCALIZATION,
    # applications: a localizer run on a log, on devices, in the simulator; evaluation
    "icploc.replay": APPLICATIONS,
    "icploc.live": APPLICATIONS,
    "icploc.hooks": APPLICATIONS,
    "icploc.mcap_export": APPLICATIONS,
    "icploc.batch": APPLICATIONS,
    "icploc.demo": APPLICATIONS,
    "icploc.plotting": APPLICATIONS,
    "icploc.sim.harness": APPLICATIONS,
    # CLI: the typer commands, and the package root (the public API, loaded lazily)
    "icploc.cli": CLI,
    "icploc.cli_args": CLI,
    "icploc.cli_app": CLI,
    "icploc.batch_cli": CLI,
    "icploc.maps.cli": CLI,
    "icploc.sim.cli": CLI,
    "icploc.logs.__main__": CLI,
    "icploc": CLI,
}


@dataclass(frozen=True)
class Import:
    source: str  # the importing module
    target: str  # the imported module of the package
    line: int
    module_level: bool  # run when the module is imported (not in a function, not TYPE_CHECKING)


def _modules() -> dict[str, Path]:
    out: dict[str, Path] = {}
    for p in sorted(PACKAGE.rglob("*.py")):
        parts = list(p.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = p
    return out


MODULES = _modules()
KNOWN = set(MODULES) | {"icploc._core"}


def _owner(name: str) -> str | None:
    """The package module an imported dotted name lives in (None: not ours)."""
    while name and name not in KNOWN:
        name = name.rpartition(".")[0]
    return name or None


def _names(module: str, is_package: bool, node: ast.Import | ast.ImportFrom) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        prefix = ".".join([*base, *([node.module] if node.module else [])])
    else:
        prefix = node.module or ""
    # ``from icploc.maps import map`` imports the submodule; ``from icploc import Map`` the root
    return [f"{prefix}.{a.name}" if f"{prefix}.{a.name}" in KNOWN else prefix for a in node.names]


def _is_type_checking(test: ast.expr) -> bool:
    return any(
        isinstance(n, ast.Name) and n.id == "TYPE_CHECKING"
        or isinstance(n, ast.Attribute) and n.attr == "TYPE_CHECKING"
        for n in ast.walk(test)
    )


def _imports(module: str, path: Path) -> list[Import]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    found: list[Import] = []

    def visit(node: ast.AST, module_level: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                visit(child, False)
            elif isinstance(child, ast.If) and _is_type_checking(child.test):
                for stmt in child.body:
                    visit(ast.Module(body=[stmt], type_ignores=[]), False)
                for stmt in child.orelse:
                    visit(ast.Module(body=[stmt], type_ignores=[]), module_level)
            elif isinstance(child, (ast.Import, ast.ImportFrom)):
                for name in _names(module, is_package, child):
                    target = _owner(name)
                    if target is not None and target != module:
                        found.append(Import(module, target, child.lineno, module_level))
            else:
                visit(child, module_level)

    visit(tree, True)
    return found


IMPORTS = [imp for m, p in MODULES.items() for imp in _imports(m, p)]


def test_every_module_has_a_layer() -> None:
    missing = sorted(KNOWN - set(LAYERS))
    assert missing == [], f"give these modules a layer in tests/test_layers.py: {missing}"


def test_the_layer_table_names_only_modules_that_exist() -> None:
    stale = sorted(set(LAYERS) - KNOWN)
    assert stale == [], f"no such modules (drop them from LAYERS): {stale}"


def test_no_module_imports_from_a_higher_layer() -> None:
    upward = [
        f"{MODULES[i.source].relative_to(PACKAGE.parent)}:{i.line}: {i.source} "
        f"({LAYER_NAMES[LAYERS[i.source]]}) imports {i.target} ({LAYER_NAMES[LAYERS[i.target]]})"
        for i in IMPORTS
        if i.source in LAYERS and i.target in LAYERS and LAYERS[i.target] > LAYERS[i.source]
    ]
    assert upward == [], "imports from a higher layer:\n" + "\n".join(upward)


def test_no_module_uses_the_deprecated_types_alias() -> None:
    users = sorted({i.source for i in IMPORTS if i.target == "icploc.types"})
    assert users == [], f"import icploc.messages instead of icploc.types in: {users}"


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            connect(v)
    return out


def _module_level_edges() -> dict[str, set[str]]:
    edges: dict[str, set[str]] = {}
    for i in IMPORTS:
        if i.module_level:
            edges.setdefault(i.source, set()).add(i.target)
    return edges


def test_module_level_imports_have_no_circle() -> None:
    circles = _cycles(_module_level_edges())
    assert circles == [], f"module-level import circles: {circles}"


@pytest.mark.parametrize(
    ("edges", "expected"),
    [
        ({"a": {"b"}, "b": {"c"}}, []),
        ({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}, [["a", "b", "c"]]),
    ],
)
def test_the_circle_finder_finds_circles(edges: dict[str, set[str]], expected: list[list[str]]) -> None:
    assert _cycles(edges) == expected


def test_the_import_reader_sees_function_level_and_relative_imports(tmp_path: Path) -> None:
    src = tmp_path / "mod.py"
    src.write_text(
        "from typing import TYPE_CHECKING\n"
        "from icploc.se2 import Pose\n"
        "if TYPE_CHECKING:\n"
        "    from icploc.maps import Map\n"
        "def f():\n"
        "    from .localizer import Localizer\n"
        "    from icploc import clock, raycast\n",
        encoding="utf-8",
    )
    got = {(i.target, i.module_level) for i in _imports("icploc.mod", src)}
    assert got == {
        ("icploc.se2", True),
        ("icploc.maps", False),
        ("icploc.localizer", False),
        ("icploc.clock", False),
        ("icploc", False),
    }
