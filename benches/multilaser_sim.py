r"""Front-only vs rear-only vs both lasers on a simulated PowerBot in a corridor.

Usage::

    nice .venv/bin/python benches/multilaser_sim.py            # 3 seeds
    nice .venv/bin/python benches/multilaser_sim.py --seeds 5 --length 20

The world: a corridor ``--length`` m long and 2 m wide, closed at both ends, no other
feature (the side walls say nothing along it). The robot drives along its centre line
from 2 m to ``length - 2`` m at 0.5 m/s; the odometry has a 3 % distance scale error and
noise. Two 180-degree PLS-like lasers (361 beams, 8 m range, 1 cm noise): the front one
at x = +0.2 m facing forward, the rear one at x = -0.2 m facing backward, each at 5 Hz,
the rear sweep 0.1 s after the front one (so the robot moves 5 cm between them: the
merger carries the rear scan to the front one's stamp by odometry). Only near an end does
a laser see a wall across the corridor: the front one the far end, the rear one the start.

Each configuration is replayed (:func:`icploc.replay.replay`, an in-memory log) from the
true start pose: ``front`` (the front laser alone, mounted by ``scan.laser_*``), ``rear``
(the rear one alone), ``both`` (``scan.lasers`` with both: merged). Reported: the position
error against the simulator's truth at each estimate (median, RMS, max) and the share of
``tracking`` estimates.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

import numpy as np

FRONT = (0.2, 0.0, 0.0)
REAR = (-0.2, 0.0, math.pi)


def corridor(length: float = 16.0, width: float = 2.0) -> np.ndarray:
    h = width / 2
    return np.array(
        [[0, -h, length, -h], [length, -h, length, h], [length, h, 0, h], [0, h, 0, -h]],
        dtype=np.float64,
    )


def simulate(
    length: float = 16.0, seed: int = 0, speed: float = 0.5, rate: float = 5.0, lag: float = 0.1,
    scale_error: float = 0.03,
) -> dict[str, Any]:  # fmt: skip
    """The corridor run: front and rear scans (frames ``front_laser`` / ``rear_laser``),
    odometry at 50 Hz, the true poses at each scan."""
    from icploc.messages import Odometry, Scan
    from icploc.se2 import compose
    from icploc.sim.world import World

    walls = corridor(length)
    world = World("corridor", walls)
    rng = np.random.default_rng(seed)
    angles = np.radians(np.linspace(-90.0, 90.0, 361))
    x0, x1 = 2.0, length - 2.0
    t_end = (x1 - x0) / speed

    def truth(t: float) -> tuple[float, float, float]:
        return (x0 + speed * min(max(t, 0.0), t_end), 0.05 * math.sin(0.4 * t), 0.0)

    odoms = []
    odo = (0.0, 0.0, 0.0)
    prev = truth(0.0)
    dt = 0.02
    for k in range(int(t_end / dt) + 10):
        t = k * dt
        now = truth(t)
        dx = (now[0] - prev[0]) * (1.0 + scale_error) + rng.normal(0, 0.0005)
        dy = (now[1] - prev[1]) + rng.normal(0, 0.0003)
        odo = compose(odo, (dx, dy, rng.normal(0, 0.0005)))
        odoms.append(Odometry(t, odo))
        prev = now
    scans, truths = [], []
    for k in range(int(t_end * rate)):
        for mount, frame, lag_ in ((FRONT, "front_laser", 0.0), (REAR, "rear_laser", lag)):
            t = k / rate + lag_
            sensor = compose(truth(t), mount)
            r = world.ranges(sensor, angles, 8.0, rng=rng, noise=0.01)
            scans.append(Scan(t, r, angles, max_range=8.0, frame=frame))
            truths.append((t, truth(t)))
    scans.sort(key=lambda s: s.stamp)
    return {"walls": walls, "scans": scans, "odometry": odoms, "truth": truth, "start": truth(0.0)}


def localize(run: dict[str, Any], which: str) -> dict[str, float]:
    """Replay ``which`` ("front", "rear", "both") of a :func:`simulate` run."""
    from icploc.config import LocalizerConfig
    from icploc.maps import Map
    from icploc.replay import replay

    if which == "both":
        cfg = LocalizerConfig.from_dict(
            {"scan": {"lasers": [
                {"name": "front_laser", "x": FRONT[0], "y": FRONT[1], "yaw": FRONT[2]},
                {"name": "rear_laser", "x": REAR[0], "y": REAR[1], "yaw": REAR[2]},
            ]}}
        )  # fmt: skip
        scans = run["scans"]
    else:
        m = FRONT if which == "front" else REAR
        cfg = LocalizerConfig.from_dict({"scan": {"laser_x": m[0], "laser_y": m[1], "laser_theta": m[2]}})
        scans = [s for s in run["scans"] if s.frame == f"{which}_laser"]
    items = sorted([*scans, *run["odometry"]], key=lambda it: it.stamp)
    res = replay(items, Map.from_lines(run["walls"]), config=cfg, initial_pose=run["start"])
    err = np.array([math.hypot(e.pose[0] - run["truth"](e.stamp)[0], e.pose[1] - run["truth"](e.stamp)[1])
                    for e in res.estimates])  # fmt: skip
    tracking = sum(1 for e in res.estimates if e.status.value == "tracking") / max(1, len(res.estimates))
    return {
        "median_m": float(np.median(err)),
        "rmse_m": float(np.sqrt(np.mean(err**2))),
        "max_m": float(err.max()),
        "tracking": tracking,
        "estimates": float(len(res.estimates)),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--length", type=float, default=16.0)
    args = ap.parse_args(argv)
    rows: dict[str, list[dict[str, float]]] = {"front": [], "rear": [], "both": []}
    for seed in range(args.seeds):
        run = simulate(args.length, seed)
        for which in rows:
            r = localize(run, which)
            rows[which].append(r)
            print(f"seed {seed} {which:5s}: median {r['median_m'] * 100:6.1f} cm, rmse {r['rmse_m'] * 100:6.1f} cm, "
                  f"max {r['max_m'] * 100:6.1f} cm, tracking {r['tracking']:.0%} ({int(r['estimates'])} estimates)",
                  flush=True)  # fmt: skip
    print(f"\ncorridor {args.length:g} m, {args.seeds} seeds (mean over seeds):")
    for which, rs in rows.items():
        mean = {k: float(np.mean([r[k] for r in rs])) for k in rs[0]}
        print(f"  {which:5s}: median {mean['median_m'] * 100:6.1f} cm, rmse {mean['rmse_m'] * 100:6.1f} cm, "
              f"max {mean['max_m'] * 100:6.1f} cm, tracking {mean['tracking']:.0%}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
