"""``icploc demo``: the paper's three experiments in its lab, through the real drivers.

The lab is 7.5 m × 7.5 m (56.25 m²) with a 5 m glass wall section and people walking
(:func:`icploc.sim.lab`). A PowerBot and a SICK PLS are simulated byte for byte on
pseudo-terminals (:mod:`icploc.sim`); the real drivers read them; the localizer runs
on every scan. Experiment 1 is a random walk of more than 20 m that ends where it
started (the paper's Table 3 / Fig. 9), experiment 2 drives circles (Table 4 /
Fig. 10), experiment 3 is a random walk along the glass wall, where 70 % of the beams
that meet the glass pass it and the paper's errors grew (Table 5 / Fig. 11). They run at
once in real time. Written to ``--out``: a plot per experiment (:func:`icploc.plotting.plot_run`:
odometry, localized trajectory and truth on the map, and the error over time),
``results.md`` with start / end points like Tables 3–5 plus the true end point, and the
TUM trajectories (``<run>.tum``) with the truth at each scan (``<run>.truth.tum``).
Errors are scored by :mod:`icploc.trajectory`.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icploc.trajectory import AteResult, Trajectory, ate, pose_errors, write_tum

__all__ = ["DemoResult", "Experiment", "experiments", "glass_walk", "run_demo"]


@dataclass
class Experiment:
    name: str
    title: str
    path: NDArray[np.float64]
    speed: float = 1.0


@dataclass
class DemoResult:
    name: str
    title: str
    stamps: NDArray[np.float64]
    localized: NDArray[np.float64]  # (N, 3)
    odometry: NDArray[np.float64]  # (N, 3), odometry mapped into the map frame at the start
    truth: NDArray[np.float64]  # (N, 3), the simulator's pose at each scan
    status: list[str]
    distance: float  # metres driven (truth)
    wall_time: float
    scans_per_second: float
    files: dict[str, Path] = field(default_factory=dict)

    @property
    def ate(self) -> AteResult:
        """The localized poses against the truth at the same scans."""
        t = Trajectory(self.stamps, self.truth)
        return ate(Trajectory(self.stamps, self.localized), t, method="nearest", max_dt=0.0)

    @property
    def errors(self) -> NDArray[np.float64]:
        """Position error (m) per scan, in time order."""
        return self.ate.position_errors

    @property
    def heading_errors_deg(self) -> NDArray[np.float64]:
        return np.asarray(np.degrees(self.ate.heading_errors), dtype=np.float64)

    def summary(self) -> dict[str, float]:
        a = self.ate
        odo_end, _ = pose_errors(self.odometry[-1:], self.truth[-1:])
        return {
            "scans": float(a.n),
            "distance_m": self.distance,
            "median_error_m": a.position.median,
            "p95_error_m": a.position.p95,
            "max_error_m": a.position.max,
            "max_heading_error_deg": math.degrees(a.heading.max),
            "odometry_end_error_m": float(odo_end[0]),
            "localized_end_error_m": float(a.position_errors[-1]),
        }


def glass_walk(length: float = 15.0, seed: int = 2) -> NDArray[np.float64]:
    """A random walk of at least ``length`` metres from the origin and back to it, its
    waypoints in the band 0.65–1.55 m from the lab's glass wall (:func:`icploc.sim.lab`:
    glass at y = 3.75 m for |x| ≤ 2.5 m), so many beams meet the glass: the
    paper's Table 5 / Fig. 11 run."""
    from icploc.sim.scenes import random_walk

    return random_walk(length, seed, box=((-2.2, 2.2), (2.2, 3.1)), start=((0.0, 0.0), (0.0, 1.5)))


def experiments(quick: bool = False) -> list[Experiment]:
    from icploc import sim as worlds

    if quick:
        walk = worlds.lab_random_walk(length=8.0, seed=5)
        circles = worlds.circle_path(radius=1.2, laps=1)
        glass = glass_walk(length=8.0, seed=2)
    else:
        walk = worlds.lab_random_walk(length=20.0, seed=13)  # a 20.7 m polyline
        circles = worlds.circle_path(radius=1.4, laps=3)
        glass = glass_walk(length=20.0, seed=2)
    return [
        Experiment("random_walk", "Random motion (Table 3, Fig. 9)", walk, speed=1.5),
        Experiment("circles", "Circle motion (Table 4, Fig. 10)", circles, speed=1.5),
        Experiment("glass", "Random motion along the glass wall (Table 5, Fig. 11)", glass,
                   speed=1.5),  # fmt: skip
    ]


def _run_one(exp: Experiment, world: Any, seed: int, out: Path) -> DemoResult:
    from icploc.sim.harness import run_simulated

    t0 = time.perf_counter()
    res, truth = run_simulated(
        world,
        exp.path,
        speed=exp.speed,
        seed=seed,
        out=out / f"{exp.name}.tum",
        timeout=120.0,
    )
    wall = time.perf_counter() - t0
    ests = res.estimates
    if not ests:
        raise RuntimeError(f"demo {exp.name}: no scans were localized")
    stamps = np.array([e.stamp for e in ests])
    loc = np.array([e.pose for e in ests])
    sim_truth = Trajectory(np.array([t for t, _ in truth]), np.array([p for _, p in truth]))
    tru, _ = sim_truth.at(stamps, method="nearest", max_dt=math.inf)  # the scan's own pose
    start = (float(exp.path[0, 0]), float(exp.path[0, 1]), 0.0)
    odo = np.full((len(ests), 3), np.nan)
    have = np.array([e.odometry is not None for e in ests], dtype=bool)
    if have.any():
        o = Trajectory(stamps[have], np.array([e.odometry for e in ests if e.odometry is not None]))
        odo[have] = o.started_at(start).poses
    dist = Trajectory(stamps, tru).path_length()
    # the truth beside the estimates, so a run can be scored again (icploc.trajectory.evaluate)
    write_tum(out / f"{exp.name}.truth.tum", Trajectory(stamps, tru))
    return DemoResult(
        name=exp.name,
        title=exp.title,
        stamps=stamps,
        localized=loc,
        odometry=odo,
        truth=tru,
        status=[e.status.value for e in ests],
        distance=dist,
        wall_time=wall,
        scans_per_second=len(ests) / max(res.wall_time, 1e-9),
        files={"trajectory": out / f"{exp.name}.tum", "truth": out / f"{exp.name}.truth.tum"},
    )


def table(r: DemoResult) -> str:
    """Start / end points like the paper's Tables 3–5 (mm, degrees), plus the truth."""

    def row(label: str, p: NDArray[np.float64]) -> str:
        return f"| {label} | {p[0] * 1000:.1f} | {p[1] * 1000:.1f} | {math.degrees(p[2]):.1f} |"

    lines = [
        f"### {r.title}",
        "",
        f"{r.distance:.1f} m driven, {len(r.stamps)} scans.",
        "",
        "| | x (mm) | y (mm) | θ (°) |",
        "|---|---:|---:|---:|",
        row("Start point (all)", r.truth[0]),
        row("End point, odometry", r.odometry[-1]),
        row("End point, localization", r.localized[-1]),
        row("End point, truth", r.truth[-1]),
        "",
    ]
    s = r.summary()
    lines.append(
        f"Localization error over the run: median {s['median_error_m'] * 1000:.1f} mm, "
        f"95th percentile {s['p95_error_m'] * 1000:.1f} mm, max {s['max_error_m'] * 1000:.1f} mm, "
        f"max heading error {s['max_heading_error_deg']:.2f}°. "
        f"Odometry end error {s['odometry_end_error_m'] * 1000:.0f} mm, "
        f"localization end error {s['localized_end_error_m'] * 1000:.1f} mm."
    )
    lines.append("")
    return "\n".join(lines)


def plot(r: DemoResult, world: Any, path: Path) -> Path:
    """The lab (walls, glass, the people's paths) with the truth, the odometry and the
    localized trajectory, and the error over time below: like the paper's Fig. 9–11."""
    from icploc.plotting import plot_run

    have = np.isfinite(r.odometry).all(axis=1)
    plot_run(
        path,
        lines=world.walls,
        glass=world.glass,
        people=[p.path for p in world.people],
        truth=Trajectory(r.stamps, r.truth),
        odometry=Trajectory(r.stamps[have], r.odometry[have]) if have.any() else None,
        localized=Trajectory(r.stamps, r.localized),
        status=r.status,
        errors=r.ate,
        title=r.title,
        dpi=110,
    )
    return path


def run_demo(
    out: str | Path = "icploc-demo",
    *,
    quick: bool = False,
    people: int = 3,
    seed: int = 0,
    parallel: bool = True,
    log: Callable[[str], None] | None = None,
) -> list[DemoResult]:
    """Run the three experiments (at once, in real time), write plots and tables to ``out``."""
    from icploc import sim as worlds

    outdir = Path(out)
    outdir.mkdir(parents=True, exist_ok=True)
    world = worlds.lab(people=people, seed=7 + seed)
    exps = experiments(quick)
    results: list[DemoResult | None] = [None] * len(exps)
    errors: list[BaseException] = []

    def work(i: int) -> None:
        try:
            results[i] = _run_one(exps[i], world, seed + 10 * i, outdir)
        except BaseException as e:  # pragma: no cover - surfaced below
            errors.append(e)

    if log:
        log(
            f"lab 7.5 m x 7.5 m, {len(world.glass)} glass section, {people} people; "
            f"PLS + PowerBot simulated on ptys; {len(exps)} experiments in real time ..."
        )
    if parallel:
        threads = [
            threading.Thread(target=work, args=(i,), name=f"demo-{e.name}")
            for i, e in enumerate(exps)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    else:
        for i in range(len(exps)):
            work(i)
    if errors:
        raise errors[0]
    done = [r for r in results if r is not None]
    md = ["# icploc demo: ICP localization in the paper's lab", ""]
    md.append(
        "Simulated PowerBot + SICK PLS (byte-exact device simulators on pseudo-terminals, "
        "read by the real drivers), lab 7.5 m × 7.5 m with a 5 m glass wall section and "
        f"{people} people walking. Odometry has wheel-scale errors and noise.\n"
    )
    for r in done:
        r.files["plot"] = plot(r, world, outdir / f"{r.name}.png")
        md.append(table(r))
    (outdir / "results.md").write_text("\n".join(md))
    return done
