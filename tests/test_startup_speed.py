"""What a replay process imports: the ``icploc replay`` start-up stays free of the parts it
does not use (pydantic for a default config, ``numpy.ma``, the device protocols), and the
helpers that keep it so answer as what they replace."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays


def _modules_after(code: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return out.stdout.split()


def test_import_icploc_imports_no_numpy() -> None:
    """The command can still set numpy's start-up (icploc.cli.start_command_process)."""
    got = _modules_after("import sys, icploc.cli\nprint(*(m for m in ('numpy',) if m in sys.modules))")
    assert got == []


def test_a_default_replay_of_a_carmen_log_imports_none_of_the_unused_parts(tmp_path: Path) -> None:
    from icploc.logs import write_carmen
    from icploc.messages import Odometry, Scan

    angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    scans = [Scan(100.0 + 0.1 * k, np.full(181, 2.0), angles) for k in range(5)]
    odoms = [Odometry(100.0 + 0.1 * k, (0.0, 0.0, 0.0)) for k in range(5)]
    log = tmp_path / "run.log"
    write_carmen(log, scans, odoms)
    code = (
        "import sys, numpy as np\n"
        "from icploc.replay import replay\n"
        "wall = np.c_[np.full(200, 2.0), np.linspace(-3, 3, 200)]\n"
        f"replay({str(log)!r}, wall, initial_pose=(0.0, 0.0, 0.0))\n"
        "unused = ('pydantic', 'numpy.ma', 'icploc.drivers.sick_protocol',"
        " 'icploc.drivers.arcos_protocol', 'icploc.drivers.recording', 'gzip')\n"
        "print(*(m for m in unused if m in sys.modules))\n"
    )
    assert _modules_after(code) == []


@given(
    arrays(
        np.float64,
        st.integers(0, 30),
        elements=st.sampled_from([0.0, 0.1, 0.1 + 1e-12, 5.0, -1.0, float("nan")]),
    )
)
def test_count_distinct_is_the_length_of_unique(a: np.ndarray) -> None:
    from icploc.logs._base import _count_distinct

    assert _count_distinct(a) == len(np.unique(a))


def test_a_map_load_through_the_prepared_map_cache_imports_no_openssl(tmp_path: Path) -> None:
    """The cache key's blake2b is hashlib's own, taken without hashlib's OpenSSL import."""
    import os

    from icploc.maps.ros import save_ros

    occ = np.zeros((40, 50), dtype=bool)
    occ[5, 5:45] = True
    save_ros(tmp_path / "m.yaml", occ, 0.05, (0.0, 0.0, 0.0))
    code = (
        "import sys\nfrom icploc.maps import Map\n"
        f"m = Map.load({str(tmp_path / 'm.yaml')!r})\n"
        "print('cache' in m.meta, *(m for m in ('hashlib', '_hashlib') if m in sys.modules))\n"
    )
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    env.pop("ICPLOC_NO_CACHE", None)
    runs = [
        subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
        for _ in range(2)
    ]
    assert [r.stdout.split() for r in runs] == [["False"], ["True"]]  # fitted and stored, then read
