"""The identifiability suite: for each backend x scenario, the mean vertex displacement (cm, over all frames and
vertices) between a rollout at a parameter's low and its high bound, the others at the prior midpoint. Small numbers
mean the parameter is hard to infer from that scenario. A parameter a backend does not have is "-"; a failed rollout
is "fail".
"""
from __future__ import annotations

import argparse

import numpy as np

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.backends.pybullet_massspring import PybulletMassSpring
from softsbi.scenarios.builtin import SCENARIOS, make_scenario

from benchmarks import runner

PARAMS = ("bend", "young", "stretch", "friction", "scale", "mass")  # young: the mujoco-flex rope


def table(grid: int = 7, rope_nodes: int = 24) -> list[dict]:
    rows = []
    for bname, sim in (("mujoco-flex", MujocoFlex(grid=grid, rope_nodes=rope_nodes)),
                       ("pybullet-massspring", PybulletMassSpring(grid=grid, rope_nodes=rope_nodes))):
        for sc_name in SCENARIOS:
            sc = make_scenario(sc_name)
            sp = sim.param_space(sc)
            mid = sp.midpoint()
            row = {"backend": bname, "scenario": sc_name}
            for n in PARAMS:
                if n not in sp.names:
                    row[n] = None
                    continue
                lo = sim.simulate(sc, dict(mid, **{n: sp[n].low}))
                hi = sim.simulate(sc, dict(mid, **{n: sp[n].high}))
                row[n] = (float(np.linalg.norm(lo.vertices - hi.vertices, axis=-1).mean() * 100)
                          if lo.ok and hi.ok else "fail")
            rows.append(row)
    return rows


FULL = None


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--grid", type=int, default=7)
    ap.add_argument("--rope-nodes", type=int, default=24)


def suite(a: argparse.Namespace) -> dict:
    rows = table(a.grid, a.rope_nodes)
    cells = [[r["backend"], r["scenario"], *[r[n] if isinstance(r[n], str) or r[n] is None else round(r[n], 2)
                                             for n in PARAMS]] for r in rows]
    return {"tables": [runner.table(f"Mean vertex displacement [cm] between a rollout at a parameter's low and at "
                                    f"its high bound, the others at the prior midpoint (grid {a.grid}, rope "
                                    f"{a.rope_nodes} nodes)", ["backend", "scenario", *PARAMS], cells)],
            "data": {"rows": rows}}
