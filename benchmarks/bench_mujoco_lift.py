"""Wall time of one mujoco-flex lift rollout (1 s simulated, 25 frames) vs grid size.

Usage::

    python benchmarks/bench_mujoco_lift.py [--grids 6 9 12 15] [--repeats 5]

Prints a table: grid, vertices, median / min wall seconds per rollout (XML build + compile +
simulate) at the prior midpoint, built-in default scenario, single thread. Stiff corners of the
prior take up to ~1.5x the midpoint time.
"""
from __future__ import annotations

import argparse
import statistics

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.scenarios.builtin import lift_scenario


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grids", type=int, nargs="+", default=[6, 9, 12, 15])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--timestep", type=float, default=0.004)
    args = ap.parse_args()
    sc = lift_scenario(None)
    print(f"{'grid':>5} {'verts':>6} {'median_s':>9} {'min_s':>7} {'status':>7}")
    for g in args.grids:
        sim = MujocoFlex(grid=g, timestep=args.timestep)
        theta = sim.param_space(sc).midpoint()
        sim.simulate(sc, theta)  # warm-up
        runs = [sim.simulate(sc, theta) for _ in range(args.repeats)]
        walls = [r.info["wall_s"] for r in runs]
        print(f"{g:>5} {g * g:>6} {statistics.median(walls):>9.3f} {min(walls):>7.3f} {runs[0].status:>7}")


if __name__ == "__main__":
    main()
