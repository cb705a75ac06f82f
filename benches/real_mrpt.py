"""MRPT ``pf-localization`` (Debian ``mrpt-apps``) on the benchmark's logs and maps.

Pipeline: our CARMEN log is rewritten for MRPT (same scans and odometry, two PARAM lines and
a laser-pose yaw offset, see below) -> ``carmen2rawlog`` -> ``.rawlog``; the map_server
YAML -> ``ros-map-yaml2mrpt`` -> ``.gridmap.gz``, whose likelihood options are patched
(below); an INI written here; ``pf-localization INI``; the estimate of each laser
observation parsed from its log ("PDF estimation: [x y phi_deg]").

Traps handled (../shared/design/PEERS.md):

* ``carmen2rawlog`` 2.5.8 mangles the timestamps: estimates are matched to scans by order
  (one estimate per laser observation), never by stamp.
* A ``.gridmap`` carries its own likelihood options (σ 0.35, decimation 5, max range 81 m),
  which win over the INI's: the values are patched in the (gunzipped) file, found by the
  byte pattern of the defaults ros-map-yaml2mrpt writes; a clear error if absent.
* MRPT spreads N beams symmetrically over ``aperture = resolution_param * N`` and ignores
  the start angle: the PARAM ``laser_front_laser_resolution`` is set so the aperture is
  ``step * (N - 1)`` and the laser pose in each line carries the yaw of the beam fan's
  centre (−step/2 for N = 180 / 360 from −90°; 0 for 181 / 361) — MRPT takes the sensor
  pose as laser pose − robot pose.
* MRPT rounds the map origin to a multiple of the resolution: the grid's x_min / y_min are
  read back from the gridmap header and the difference is applied to the initial pose and
  taken off every estimate.
* It seeds itself from the clock: each run differs; ``runs`` > 1 repeats and reports all.

Settings (PEERS.md's that worked): KLD 500-2000 particles, likelihood field σ 0.2 m,
zHit 0.95, zRandom 0.05, max correspondence distance 0.3 m, ~60 beams (decimation
N // 60), update on every scan, odometry min std 0.02 m / 1°; initial particles uniform in
±0.1 m / ±3° around the given start.
"""

from __future__ import annotations

import gzip
import math
import re
import shutil
import struct
import subprocess
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["available", "run_mrpt"]

TOOLS = ("carmen2rawlog", "ros-map-yaml2mrpt", "pf-localization")

LF = {"std": 0.2, "zhit": 0.95, "zrand": 0.05, "maxcorr": 0.3}


def available() -> bool:
    return all(shutil.which(t) for t in TOOLS)


def _fan(n: int) -> tuple[float, float]:
    """(step, centre yaw) of an n-reading FLASER fan (CARMEN convention)."""
    if n % 2 == 0:
        step = math.pi / n
        return step, -step / 2
    return math.pi / (n - 1), 0.0


def write_mrpt_carmen(
    path: Path, ranges: NDArray[np.float64], odom: NDArray[np.float64], max_range: float
) -> None:
    n = ranges.shape[1]
    step, yaw = _fan(n)
    res_deg = math.degrees(step * (n - 1)) / n
    with open(path, "w") as f:
        f.write(f"PARAM robot_front_laser_max {max_range:.3f}\n")
        f.write(f"PARAM laser_front_laser_resolution {res_deg:.9f}\n")
        for k, (r, o) in enumerate(zip(ranges, odom, strict=True)):
            rs = " ".join(f"{v:.3f}" for v in r)
            # the laser pose: the robot pose turned by the fan's centre yaw
            lx, ly, lt = o[0], o[1], o[2] + yaw
            f.write(
                f"FLASER {n} {rs} {lx:.6f} {ly:.6f} {lt:.9f} {o[0]:.6f} {o[1]:.6f} {o[2]:.9f} "
                f"{k * 0.1:.3f} bench {k * 0.1:.3f}\n"
            )


def _patch_gridmap(src: Path, dst: Path, max_range: float, decimation: int) -> tuple[float, float]:
    """Write ``dst`` (gzip) with our likelihood options; return the grid's (x_min, y_min)."""
    raw = gzip.open(src).read() if src.suffix == ".gz" else src.read_bytes()
    name = b"mrpt::maps::COccupancyGridMap2D"
    at = raw.find(name)
    if at < 0:
        raise ValueError(f"{src}: not an MRPT COccupancyGridMap2D file")
    hdr = at + len(name) + 2  # version byte, bits-per-cell byte
    _sx, _sy, x_min, _x_max, y_min = struct.unpack_from("<IIfff", raw, hdr)
    pattern = struct.pack("<fff", 0.35, 0.95, 0.05)
    i = raw.rfind(pattern)
    if i < 0 or raw.count(pattern) != 1:
        raise ValueError(
            f"{src}: likelihood options of ros-map-yaml2mrpt (0.35 / 0.95 / 0.05) not found once; "
            "the format changed: cannot override them"
        )
    buf = bytearray(raw)
    struct.pack_into("<ffff", buf, i, LF["std"], LF["zhit"], LF["zrand"], max_range)
    struct.pack_into("<I", buf, i + 16, decimation)
    struct.pack_into("<f", buf, i + 20, LF["maxcorr"])
    with gzip.open(dst, "wb") as f:
        f.write(bytes(buf))
    return float(x_min), float(y_min)


INI = """\
[MetricMap]
occupancyGrid_count=1

[MetricMap_occupancyGrid_00_creationOpts]
resolution={res}

[MetricMap_occupancyGrid_00_likelihoodOpts]
likelihoodMethod=lmLikelihoodField_Thrun
LF_stdHit={std}
LF_zHit={zhit}
LF_zRandom={zrand}
LF_maxRange={max_range}
LF_decimation={decimation}
LF_maxCorrsDistance={maxcorr}
enableLikelihoodCache=true

[KLD_options]
KLD_binSize_PHI_deg=2.5
KLD_binSize_XY=0.10
KLD_delta=0.01
KLD_epsilon=0.02
KLD_maxSampleSize=2000
KLD_minSampleSize=500
KLD_minSamplesPerBin=0

[PF_options]
PF_algorithm=pfStandardProposal
resamplingMethod=prMultinomial
adaptiveSampleSize=1
BETA=0.5
sampleSize=1

[DummyOdometryParams]
minStdXY=0.02
minStdPHI=1.0

[LocalizationExperiment]
rawlog_file={rawlog}
map_file={gridmap}
logOutput_dir={outdir}
particles_count=1000
init_PDF_mode=1
init_PDF_min_x={x0}
init_PDF_max_x={x1}
init_PDF_min_y={y0}
init_PDF_max_y={y1}
init_PDF_min_yaw_deg={t0}
init_PDF_max_yaw_deg={t1}
experimentRepetitions=1
SAVE_STATS_ONLY=false
3DSceneFrequency=-1
SHOW_PROGRESS_3D_REAL_TIME=false
"""

_EST = re.compile(r"PDF estimation:\s*[\[(]\s*([-+0-9.eE]+)[ ,]+([-+0-9.eE]+)[ ,]+([-+0-9.eE]+)")


def _children_cpu() -> float:
    """User + system CPU seconds of the finished child processes (hook: clispeed)."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_mrpt(
    work: Path,
    ranges: NDArray[np.float64],
    odom: NDArray[np.float64],
    map_yaml: Path,
    pose: tuple[float, float, float],
    max_range: float,
    timeout: float = 1800.0,
) -> dict:
    """One pf-localization run; returns poses (one per scan, in our map frame), the
    whole-process time of pf-localization and the conversion times."""
    work.mkdir(parents=True, exist_ok=True)
    n = ranges.shape[1]
    carmen = work / "mrpt_input.log"
    write_mrpt_carmen(carmen, ranges, odom, max_range)
    rawlog = work / "input.rawlog"
    t0 = time.perf_counter()
    subprocess.run(
        ["carmen2rawlog", "-i", str(carmen), "-o", str(rawlog), "-w", "-q"],
        check=True, capture_output=True, timeout=timeout,
    )  # fmt: skip
    t_conv = time.perf_counter() - t0
    mapdir = work / "map"
    mapdir.mkdir(exist_ok=True)
    local_yaml = mapdir / map_yaml.name
    shutil.copy(map_yaml, local_yaml)
    import yaml

    meta = yaml.safe_load(map_yaml.read_text())
    shutil.copy(map_yaml.parent / meta["image"], mapdir / meta["image"])
    subprocess.run(
        ["ros-map-yaml2mrpt", "-i", str(local_yaml), "-w", "-q"],
        check=True, capture_output=True, timeout=timeout,
    )  # fmt: skip
    produced = sorted(mapdir.glob("*.gridmap*"))
    if not produced:
        raise RuntimeError(f"ros-map-yaml2mrpt wrote no .gridmap in {mapdir}")
    decimation = max(1, n // 60)
    gridmap = work / "map_patched.gridmap.gz"
    x_min, y_min = _patch_gridmap(produced[0], gridmap, max_range, decimation)
    off = (x_min - float(meta["origin"][0]), y_min - float(meta["origin"][1]))
    x, y, th = pose[0] + off[0], pose[1] + off[1], pose[2]
    ini = work / "pf.ini"
    ini.write_text(
        INI.format(
            res=meta["resolution"], max_range=max_range, decimation=decimation,
            rawlog=rawlog, gridmap=gridmap, outdir=work / "out",
            x0=x - 0.1, x1=x + 0.1, y0=y - 0.1, y1=y + 0.1,
            t0=math.degrees(th) - 3.0, t1=math.degrees(th) + 3.0, **LF,
        )
    )  # fmt: skip
    t1, c1 = time.perf_counter(), _children_cpu()
    proc = subprocess.run(
        ["pf-localization", str(ini)], capture_output=True, text=True, timeout=timeout,
        stdin=subprocess.DEVNULL,
    )  # fmt: skip
    t_run, c_run = time.perf_counter() - t1, _children_cpu() - c1
    (work / "pf.stdout").write_text(proc.stdout + "\n--- stderr ---\n" + proc.stderr)
    if proc.returncode != 0:
        raise RuntimeError(f"pf-localization exit {proc.returncode}; see {work / 'pf.stdout'}")
    est = [
        (float(m.group(1)) - off[0], float(m.group(2)) - off[1], math.radians(float(m.group(3))))
        for m in _EST.finditer(proc.stdout + proc.stderr)
    ]
    if len(est) != len(ranges):
        raise RuntimeError(
            f"pf-localization gave {len(est)} estimates for {len(ranges)} scans; see {work / 'pf.stdout'}"
        )
    return {
        "poses": [list(p) for p in est],
        "status": None,
        "time_s": t_run,
        "cpu_s": c_run,  # hook (clispeed): pf-localization's user + system CPU
        "convert_s": t_conv,
        "origin_offset": off,
    }
