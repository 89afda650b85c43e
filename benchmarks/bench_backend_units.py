"""The backend-units suite: a clamped strip's droop on both backends at the same physical parameters.

A square cloth (side 0.2 m, 9x9 grid) has its first 5 grid rows pinned (a clamped edge, overhang
a = 0.1 m); gravity points up so the table never touches it (:func:`softsbi.backends.common.cantilever_scenario`).
After ``--duration`` simulated seconds (settled) the tip deflection is the mean rise of the free
edge; the analytic small-deflection value is ``w a^4 / (8 D)``, ``w = mass g`` (valid while it is below a).
"""
from __future__ import annotations

import argparse
import time

from softsbi.backends.common import cantilever_analytic, cantilever_scenario, cantilever_tip_deflection

from benchmarks.runner import table

#: static runs: less damping than the dynamic defaults so the strip settles (pybullet 0.02 is its stable minimum)
OPTIONS = {"mujoco-flex": {"damping": 0.01}, "pybullet-massspring": {"damping": 0.02}}


def measure(bends, mass=0.2, stretch=100.0, grid=9, g=9.81, duration=16.0):
    """One JSON row per rigidity: analytic, each engine's tip deflection (m), status and wall time."""
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.backends.pybullet_massspring import PybulletMassSpring
    clamp = (grid + 1) // 2
    sc = cantilever_scenario(grid=grid, clamp_rows=clamp, g=g, duration=duration)
    sims = {"mujoco-flex": MujocoFlex(grid=grid, **OPTIONS["mujoco-flex"]),
            "pybullet-massspring": PybulletMassSpring(grid=grid, **OPTIONS["pybullet-massspring"])}
    rows = []
    for b in bends:
        th = {"bend": b, "stretch": stretch, "friction": 0.5, "scale": 0.2, "mass": mass}
        row = {"bend": b, "g": g, "grid": grid,
               "analytic_m": cantilever_analytic(b, mass, grid=grid, clamp_rows=clamp, g=g)}
        for name, sim in sims.items():
            t0 = time.perf_counter()
            ro = sim.simulate(sc, th)
            row[name] = cantilever_tip_deflection(ro.vertices, grid) if ro.ok else None
            row[name + "_status"] = ro.reason or "ok"
            row[name + "_s"] = round(time.perf_counter() - t0, 2)
        rows.append(row)
    return rows


FULL = {"bends": [1e-4, 2e-4, 3e-4, 5e-4, 1e-3], "g": [9.81, 1.0]}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--bends", type=float, nargs="+", default=[2e-4, 3e-4, 1e-3], help="bending rigidities D, N m")
    ap.add_argument("--mass", type=float, default=0.2, help="areal density, kg/m^2")
    ap.add_argument("--g", type=float, nargs="+", default=[9.81], help="gravity, m/s^2 (points up)")
    ap.add_argument("--grid", type=int, default=9)
    ap.add_argument("--duration", type=float, default=16.0, help="simulated seconds to settle")


def suite(a: argparse.Namespace) -> dict:
    rows = [r for g in a.g for r in measure(a.bends, a.mass, grid=a.grid, g=g, duration=a.duration)]
    cm = lambda v: None if v is None else round(100 * v, 2)  # noqa: E731
    out = []
    for r in rows:
        mj, pb = r["mujoco-flex"], r["pybullet-massspring"]
        out.append([r["g"], r["bend"], cm(r["analytic_m"]), cm(mj), cm(pb),
                    None if mj is None or pb is None else cm(pb - mj)])
    return {"tables": [table(f"Tip deflection of the clamped strip [cm], grid {a.grid}, mass {a.mass} kg/m^2, "
                             f"{a.duration:g} s to settle",
                             ["g [m/s^2]", "D [N m]", "Euler-Bernoulli w a^4/(8D)", "mujoco-flex",
                              "pybullet-massspring", "pybullet - mujoco"], out,
                             note="The Euler-Bernoulli value holds for small deflections only (below the overhang, "
                                  "10 cm).")],
            "data": {"rows": rows}}
