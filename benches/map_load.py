"""Map load time: cold, in a fresh process, with and without the cache of prepared maps.

    .venv/bin/python benches/map_load.py                      # Willow Garage 0.05 and 0.1
    .venv/bin/python benches/map_load.py --map some.yaml      # any map
    .venv/bin/python benches/map_load.py --build LOG --resolution 0.08   # build one first

For each map: whole-process wall time of ``python -c 'import icploc; Map.load(...)'``, and
the ``Map.load`` time inside it, (a) with no cache (``cache=False``: read, trace, fit),
(b) filling an empty cache, (c) from the cache. Each figure is the median of ``--repeat``
fresh processes. The cache lives in a temporary XDG_CACHE_HOME (the user's is untouched).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

CHILD = """
import json, sys, time
t0 = time.perf_counter()
import icploc
from icploc.maps import Map
t1 = time.perf_counter()
m = Map.load(sys.argv[1], cache={cache})
t2 = time.perf_counter()
m.index(0.05)
t3 = time.perf_counter()
print(json.dumps({{"import_s": t1 - t0, "load_s": t2 - t1, "index_s": t3 - t2,
  "lines": len(m.lines), "points": len(m.extra_points), "shape": list(m.grid.shape),
  "explained": m.meta["fit"]["explained_fraction"], "cached": "cache" in m.meta}}))
"""


def run(path: Path, cache: str, env: dict[str, str]) -> dict[str, float]:
    t = time.perf_counter()
    out = subprocess.run(
        [sys.executable, "-c", CHILD.format(cache=cache), str(path)],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    ).stdout
    d = json.loads(out.strip().splitlines()[-1])
    d["process_s"] = time.perf_counter() - t
    return d


def bench(path: Path, repeat: int) -> dict[str, object]:
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, XDG_CACHE_HOME=tmp)
        env.pop("ICPLOC_NO_CACHE", None)
        rows: dict[str, list[dict[str, float]]] = {"no_cache": [], "fill": [], "cached": []}
        for _ in range(repeat):
            rows["no_cache"].append(run(path, "False", env))
        for _ in range(repeat):
            for f in Path(tmp).rglob("*.npz"):
                f.unlink()
            rows["fill"].append(run(path, "None", env))
            rows["cached"].append(run(path, "None", env))
    res: dict[str, object] = {"map": str(path)}
    first = rows["no_cache"][0]
    res.update(shape=first["shape"], lines=first["lines"], points=first["points"],
               explained=first["explained"])
    for k, v in rows.items():
        res[k] = {
            m: round(statistics.median(r[m] for r in v), 3)
            for m in ("process_s", "import_s", "load_s", "index_s")
        }
    assert all(r["cached"] for r in rows["cached"])
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--map", type=Path, action="append", help="map file(s) to time")
    ap.add_argument("--build", type=Path, help="build a map from this log first (icploc map build)")
    ap.add_argument("--resolution", type=float, default=0.1, help="cell size for --build [m]")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    maps = list(a.map or [])
    tmpdir = None
    if a.build is not None:
        tmpdir = tempfile.TemporaryDirectory()
        out = Path(tmpdir.name) / (a.build.name.split(".")[0] + ".yaml")
        subprocess.run(
            [sys.executable, "-m", "icploc.cli", "map", "build", str(a.build), "--out", str(out),
             "--resolution", str(a.resolution)],
            check=True,
        )
        maps.append(out)
    if not maps:
        w = DATA / "maps" / "willow_garage"
        maps = [w / "willow-full-0.05.yaml", w / "willow-full-0.1.yaml"]
    for p in maps:
        print(json.dumps(bench(p, a.repeat)))
    if tmpdir is not None:
        tmpdir.cleanup()


if __name__ == "__main__":
    main()
