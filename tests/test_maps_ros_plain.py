"""The map_server YAML fast path (icploc.maps.ros.plain_mapping) reads what PyYAML reads,
or declines (None) and PyYAML reads the file."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml
from hypothesis import given
from hypothesis import strategies as st
from icploc.maps.ros import plain_mapping

#: tokens that YAML 1.1 reads as something else than they look, and ordinary ones
TOKENS = [
    "0", "1", "-3", "+5", "00", "0755", "1_000", "0x1f", "12:30", "1.5", "-0.25", "1.", "01.5",
    ".5", "-.5", "1e5", "1.5e10", "1.5e+10", "2.0E-3", ".inf", "-.inf", ".nan", "inf", "nan",
    "yes", "No", "TRUE", "off", "On", "null", "Null", "~", "y", "n", "trinary", "map.pgm",
    "/abs/map.pgm", "a/b-c_d.pgm", "2020-01-02", "a:b", "'quoted'", '"q"', "[1, 2, 3]",
    "[1,2]", "[ -1.0 , 0.5 ]", "[]", "[a, b]", "{a: 1}", "x #c", "x#c", "0.1 # note", "",
]  # fmt: skip
KEYS = ["image", "resolution", "origin", "mode", "yes", "a.b", "_k", "1k", "k k", "/p"]


@st.composite
def files(draw: st.DrawFn) -> str:
    lines = []
    for _ in range(draw(st.integers(0, 7))):
        kind = draw(st.sampled_from(["pair", "pair", "pair", "comment", "blank", "odd", "odd"]))
        if kind == "pair":
            sep = draw(st.sampled_from([": ", ":  ", ":", " : ", ":\t"]))
            lines.append(draw(st.sampled_from(KEYS)) + sep + draw(st.sampled_from(TOKENS)))
        elif kind == "comment":
            lines.append(draw(st.sampled_from(["# a comment", "  # indented", "#"])))
        elif kind == "blank":
            lines.append(draw(st.sampled_from(["", "   ", "\r"])))
        else:
            lines.append(draw(st.sampled_from(["---", "...", "  nested: 1", "- item", "k:\r",
                                               "origin:", "- 0.0", "- -1", "  - 2.5", "-1",
                                               "- 1e5", "-  3", "- yes", "  x: 1"])))  # fmt: skip
    return draw(st.sampled_from(["\n", "\r\n"])).join(lines) + draw(st.sampled_from(["", "\n"]))


@given(files())
def test_the_fast_path_reads_what_pyyaml_reads_or_declines(text: str) -> None:
    got = plain_mapping(text)
    if got is not None:
        assert (got, [type(v) for v in got.values()]) == (
            (want := yaml.safe_load(text)),
            [type(v) for v in want.values()],
        )


def test_a_map_server_file_takes_the_fast_path() -> None:
    text = (
        "image: intel_10cm.pgm\nresolution: 0.1\norigin: [-20.900000, -24.300000, 0.0]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    assert plain_mapping(text) == yaml.safe_load(text)


def test_a_block_list_takes_the_fast_path() -> None:
    text = "image: m.pgm\norigin:\n- 0.0\n- -1.5\n- 0\nnegate: 0\n"
    assert plain_mapping(text) == yaml.safe_load(text)


def test_loading_a_map_server_map_imports_no_yaml(tmp_path: Path) -> None:
    import numpy as np
    from icploc.maps.ros import save_ros

    occ = np.zeros((40, 50), dtype=bool)
    occ[5, 5:45] = True
    code = (
        "import sys\nfrom icploc.maps import Map\n"
        f"Map.load({str(tmp_path / 'm.yaml')!r}, cache=False)\nprint('yaml' in sys.modules)\n"
    )
    save_ros(tmp_path / "m.yaml", occ, 0.05, (0.0, 0.0, 0.0))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
