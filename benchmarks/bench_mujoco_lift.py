"""The mujoco-lift suite: wall time of one mujoco-flex lift rollout (1 s simulated, 25 frames) against grid size.

Median and minimum wall seconds per rollout (XML build + compile + simulate) at the prior midpoint of the built-in
lift, single thread, after one warm-up rollout. Stiff corners of the prior take up to ~1.5x the midpoint time.
"""
from __future__ import annotations

import argparse
import statistics

from benchmarks.runner import table

FULL = {"grids": [6, 9, 12, 15], "repeats": 5}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--grids", type=int, nargs="+", default=[6, 9])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--timestep", type=float, default=0.004)


def suite(a: argparse.Namespace) -> dict:
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.scenarios.builtin import lift_scenario

    sc = lift_scenario(None)
    rows = []
    for g in a.grids:
        sim = MujocoFlex(grid=g, timestep=a.timestep)
        theta = sim.param_space(sc).midpoint()
        sim.simulate(sc, theta)  # warm-up
        runs = [sim.simulate(sc, theta) for _ in range(a.repeats)]
        walls = [r.info["wall_s"] for r in runs]
        rows.append([g, g * g, round(statistics.median(walls), 3), round(min(walls), 3), runs[0].status])
    return {"tables": [table(f"One lift rollout (timestep {a.timestep} s), {a.repeats} repeats",
                             ["grid", "vertices", "median s", "min s", "status"], rows)]}
