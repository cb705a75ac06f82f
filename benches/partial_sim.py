"""The simulated building whose map lacks a wing (tests/partial_world.py), localized with
the default settings (the outside-the-map state on) and with it turned off
(``--no-partial-map``, config ``outside.enabled: false``; skipped with --no-plain); prints the false-tracking count, the errors inside
the map and the map patch's walls against the true ones: all its wall cells in the wing,
and those it is sure of (the sigma of where their walls are drawn at most
icploc.mappatch.PATCH_SIGMA_BOUND, from the pose graph's covariance); and per stretch the
chain's heading against the true poses (its scan match's bias per match, the chain's and
the graph's heading error).

    .venv/bin/python benches/partial_sim.py [--seed N] [--no-plain]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from partial_world import WING_BOX, partial_run, wall_distance  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--no-plain", action="store_true",
        help="skip the run with the outside-the-map state turned off (outside.enabled false)",
    )  # fmt: skip
    a = ap.parse_args(argv)
    from icploc.config import LocalizerConfig
    from icploc.localizer import Localizer, run
    from icploc.mappatch import PATCH_SIGMA_BOUND, patch_solution

    r, m = partial_run(a.seed)
    modes = ["default"] + ([] if a.no_plain else ["--no-partial-map"])
    for mode in modes:
        # the public API as the README shows it: the default config attaches the
        # outside-the-map monitor; --no-partial-map: outside.enabled false
        cfg = LocalizerConfig() if mode == "default" else LocalizerConfig.from_dict(
            {"outside": {"enabled": False}}
        )
        loc = Localizer(m, cfg, initial_pose=tuple(r.truth[0]))
        mon = loc.outside
        if mon is not None:
            mon.record = True  # the stretches' scans, for the patch below
        try:
            ests = run(loc, r.items)
        except Exception as exc:  # noqa: BLE001 - a bench line, not a crash: say it and go on
            print(f"{mode}: the run died: {type(exc).__name__}: {exc}")
            continue
        p = np.array([e.pose for e in ests])
        e = np.hypot(p[:, 0] - r.truth[:, 0], p[:, 1] - r.truth[:, 1])
        st = np.array([x.status.value for x in ests])
        mapped = np.array([x.mapped for x in ests])
        print(
            f"{mode}: {len(ests)} scans, tracking > 0.5 m off: "
            f"{int(np.sum((st == 'tracking') & (e > 0.5)))}, max error {e.max():.2f} m, "
            f"scans reported inside the map: median {np.median(e[mapped]) * 100:.1f} cm, "
            f"p95 {np.percentile(e[mapped], 95) * 100:.1f} cm; outside: {int((~mapped).sum())}"
        )
        if mon is None:
            continue
        for line in mon.summary_lines(len(ests)):
            print("  " + line)
        g, sigma = patch_solution(mon.stretches, resolution=float(m.resolution), walls=mon.walls)
        if g is None or sigma is None:
            continue
        occ = np.argwhere(g.occupied)
        xy = np.asarray(g.origin[:2]) + (occ[:, ::-1] + 0.5) * g.resolution
        x0, y0, x1, y1 = WING_BOX
        box = (xy[:, 0] > x0 + 0.5) & (xy[:, 0] < x1 + 0.5) & (xy[:, 1] > y0 - 0.5) & (xy[:, 1] < y1 + 0.5)
        d = wall_distance(r.world, xy[box])
        print(
            f"  patch: {len(d)} wall cells in the wing, distance to the true walls: median "
            f"{np.median(d) * 100:.1f} cm, within 10 cm {np.mean(d <= 0.1) * 100:.1f} %, "
            f"p95 {np.percentile(d, 95) * 100:.1f} cm, max {d.max() * 100:.1f} cm"
        )
        sure = sigma[occ[box, 0], occ[box, 1]] <= PATCH_SIGMA_BOUND
        dc = d[sure]
        print(
            f"  confident cells (sigma <= {PATCH_SIGMA_BOUND * 100:.0f} cm): {len(dc)} "
            f"({np.mean(sure) * 100:.1f} %), within 10 cm "
            + (f"{np.mean(dc <= 0.1) * 100:.1f} %, max {dc.max() * 100:.1f} cm" if len(dc) else "-")
            + f"; cells more than 10 cm off: {int(np.sum(d > 0.1))}, "
            f"of them flagged unsure {int(np.sum((d > 0.1) & ~sure))}"
        )
        _chain_lines(mon.stretches, r.truth, mon.walls)
    return 0


def _chain_lines(stretches: list, truth: np.ndarray, walls: object) -> None:
    """Per stretch back in the map, the chain's heading against the true poses: its scan
    match's bias (each scan against its previous five drawn at their true poses,
    icploc.mappatch.chain_heading_errors) and the heading error of the chain itself
    (odometry fused with those matches, icploc.mappatch.refined_poses) and of the graph."""
    import math

    from icploc.mappatch import _stretch_poses, chain_heading_errors, refined_poses

    for n, st in enumerate(stretches):
        if st.lock_pose is None or st.correction is None or len(st.scans) < 10:
            continue
        k = np.array([i for i, _, _ in st.scans])
        t = truth[k]  # a stretch's scan index is the run's frame index
        scans = [p for _, p, _ in st.scans]
        coasted = [p for _, _, p in st.scans]
        c, lock = st.correction, st.lock_pose
        coasted[-1] = (lock[0] - c[0], lock[1] - c[1], lock[2] - c[2])
        e = np.degrees(chain_heading_errors(scans, t))
        chain, _ = refined_poses(st.exit_pose, scans, coasted)
        graph = _stretch_poses(st, True, walls)  # type: ignore[arg-type]

        def head(p: np.ndarray, t: np.ndarray = t) -> np.ndarray:
            return np.degrees(np.remainder(p[:, 2] - t[:, 2] + math.pi, 2 * math.pi) - math.pi)

        hc, ho, hg = head(np.asarray(chain)), head(np.asarray(coasted)), head(np.asarray(graph))
        print(
            f"  stretch {n} chain: scan match's heading bias at the true poses "
            f"{e.mean():+.4f} deg per match (+- {e.std() / math.sqrt(len(e)):.4f}, {len(e)} matches); "
            f"heading error at the lock: odometry {ho[-1]:+.2f}, chain {hc[-1]:+.2f} deg "
            f"(max {np.abs(hc).max():.2f}); graph max {np.abs(hg).max():.2f} deg"
        )


if __name__ == "__main__":
    raise SystemExit(main())
