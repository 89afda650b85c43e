"""Cantilever droop on both backends at the same physical parameters (issue 15 item 6).

A square cloth (side ``L``) lies flat; the rows of grid vertices with x <= ``clamp`` are pinned
(a clamped edge), gravity points *up* (+z, so the table below never touches the strip), and the
free overhang ``a = L - clamp`` droops. After ``T`` s (damped to rest) the tip deflection is the
mean height of the free edge's vertices above the clamp. Small-deflection Euler-Bernoulli beam
(plate strip, width-independent): ``delta = w a^4 / (8 D)``, ``w = mass * g`` N/m^2.

Run:  PYTHONPATH=. python benchmarks/bench_backend_units.py [--bends 1e-4,3e-4,1e-3]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from softsbi.scenarios.spec import load_scenario_data

L, GRID, CLAMP_ROWS, G = 0.2, 9, 5, 9.81


def cantilever_scenario(L: float = L, grid: int = GRID, clamp_rows: int = CLAMP_ROWS, g: float = G,
                        duration: float = 2.0):
    """The clamped-strip scenario: ``clamp_rows`` grid rows pinned (x <= (clamp_rows-1) h), gravity +z."""
    h = L / (grid - 1)
    handles = []
    for i in range(clamp_rows):
        for j in range(grid):
            p = [h * i, h * j, 0.0]
            if i == 0 and j == 0:  # the spec needs one handle on a path: a path that stands still
                handles.append({"name": "h0_0", "grasp": {"point": p},
                                "path": {"keyframes": [{"t": 0.0, "p": p}, {"t": duration, "p": p}]}})
            else:
                handles.append({"name": f"h{i}_{j}", "grasp": {"point": p}, "pinned": True})
    data = {"format": "softsbi-scenario/1", "name": "cantilever", "object": {"kind": "cloth", "size": L},
            "placement": {"corner": [0.0, 0.0], "direction": [1.0, 1.0]}, "handles": handles,
            "frames": {"count": 11, "duration": duration}, "world": {"table_z": 0.0, "gravity": [0.0, 0.0, g]}}
    return load_scenario_data(data, "<cantilever>", None)


def tip_deflection(ro, grid: int = GRID) -> float:
    """Mean height (m) of the free edge (grid row i = grid-1) above the clamped row at the last frame."""
    v = ro.vertices[-1].reshape(grid, grid, 3)
    v0 = ro.vertices[0].reshape(grid, grid, 3)
    return float((v[-1, :, 2] - v0[-1, :, 2]).mean())


def analytic(bend: float, mass: float, L: float = L, grid: int = GRID, clamp_rows: int = CLAMP_ROWS,
             g: float = G) -> float:
    a = L - (clamp_rows - 1) * L / (grid - 1)
    return mass * g * a ** 4 / (8.0 * bend)


#: static runs: less damping than the dynamic defaults so the strip settles (pybullet 0.02 is its stable minimum)
OPTIONS = {"mujoco-flex": {"damping": 0.01}, "pybullet-massspring": {"damping": 0.02}}


def measure(bends, mass=0.2, stretch=100.0, grid=GRID, g=G, duration=16.0):
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.backends.pybullet_massspring import PybulletMassSpring
    sc = cantilever_scenario(grid=grid, g=g, duration=duration)
    sims = {"mujoco-flex": MujocoFlex(grid=grid, **OPTIONS["mujoco-flex"]),
            "pybullet-massspring": PybulletMassSpring(grid=grid, **OPTIONS["pybullet-massspring"])}
    rows = []
    for b in bends:
        th = {"bend": b, "stretch": stretch, "friction": 0.5, "scale": L, "mass": mass}
        row = {"bend": b, "g": g, "analytic_m": analytic(b, mass, g=g)}
        for name, sim in sims.items():
            t0 = time.perf_counter()
            ro = sim.simulate(sc, th)
            row[name] = tip_deflection(ro, grid) if ro.ok else None
            row[name + "_status"] = ro.reason or "ok"
            row[name + "_s"] = time.perf_counter() - t0
        rows.append(row)
        print(json.dumps(row))
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--bends", default="3e-5,1e-4,3e-4,1e-3")
    ap.add_argument("--mass", type=float, default=0.2)
    ap.add_argument("--g", type=float, default=G, help="gravity, m/s^2 (points up)")
    ap.add_argument("--duration", type=float, default=16.0, help="simulated seconds to settle")
    a = ap.parse_args()
    measure([float(x) for x in a.bends.split(",")], a.mass, g=a.g, duration=a.duration)
