"""The render suite: ms per rendered frame of each backend at a few image sizes, and the rollout overhead of
``simulate_images`` over ``simulate`` (wipe scenario, grid 9, 31 frames).

With ``--figures`` it also writes the contact sheets ``docs/figures/render_wipe_mujoco.png`` and
``docs/figures/render_wipe_pybullet.png``. ``ms/frame`` is the time inside the per-frame render hook (colour + depth
+ segmentation, robot included) divided by the number of frames, without the once-per-rollout set-up (GL context,
colours, robot bodies: ``set-up ms``); ``overhead`` is the extra wall time of the whole rendered rollout (model/GL
set-up included) over a plain ``simulate``. Medians of ``--repeats`` runs on a shared machine.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.backends.pybullet_massspring import PybulletMassSpring
from softsbi.scenarios.builtin import wipe_scenario
from softsbi.scenarios.cameras import scenario_camera
from softsbi.perception.render import save_frames_png

from benchmarks.runner import table

ROOT = Path(__file__).resolve().parents[1]
BACKENDS = {"mujoco-flex": MujocoFlex, "pybullet-massspring": PybulletMassSpring}
FIGURES = {"mujoco-flex": "render_wipe_mujoco.png", "pybullet-massspring": "render_wipe_pybullet.png"}


def _median_time(fn, repeats):
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        r = fn()
        out.append((time.perf_counter() - t, r))
    walls = [w for w, _ in out]
    return statistics.median(walls), out[-1][1]


def bench(sizes, repeats, grid=9):
    sc = wipe_scenario()
    T = sc.n_frames
    rows = []
    for name, cls in BACKENDS.items():
        sim = cls(grid=grid)
        th = sim.param_space(sc).midpoint()
        sim.simulate(sc, th)  # warm-up (imports, clients)
        t_sim, _ = _median_time(lambda sim=sim, th=th: sim.simulate(sc, th), repeats)
        for size in sizes:
            cam = scenario_camera(sc, size)
            sim.simulate_images(sc, th, cam)  # warm-up (GL context)
            renders = []
            t_img, _ = _median_time(lambda sim=sim, th=th, cam=cam: sim.simulate_images(sc, th, cam), repeats)
            setups = []
            for _ in range(repeats):
                info = sim.simulate_images(sc, th, cam).info
                renders.append(info["render_s"] - info["render_setup_s"])
                setups.append(info["render_setup_s"])
            ms = 1000.0 * statistics.median(renders) / T
            rows.append({"backend": name, "size": size, "frames": T, "grid": grid, "ms_per_frame": round(ms, 2),
                         "setup_ms": round(1000.0 * statistics.median(setups), 1),
                         "simulate_s": round(t_sim, 3), "simulate_images_s": round(t_img, 3),
                         "overhead_s": round(t_img - t_sim, 3), "overhead_x": round(t_img / t_sim, 2)})
    return rows


def figures(size=192, n=6, grid=9):
    sc = wipe_scenario()
    cam = scenario_camera(sc, size)  # +x (the drag direction, towards the robot) at the image top
    idx = np.linspace(0, sc.n_frames - 1, n).round().astype(int)
    for name, cls in BACKENDS.items():
        sim = cls(grid=grid)
        ro = sim.simulate_images(sc, sim.param_space(sc).midpoint(), cam)
        path = ROOT / "docs" / "figures" / FIGURES[name]
        save_frames_png(ro.rgb[idx], path, ncols=n, labels=[f"t = {ro.times[k]:.2f} s" for k in idx],
                        title=f"{name}: wipe, grid {grid}, prior midpoint, {size} px", scale=1.0)
        yield {"path": "figures/" + FIGURES[name], "caption": f"{name}: wipe, grid {grid}, prior midpoint"}


FULL = {"sizes": [64, 128, 320], "repeats": 3, "figures": True}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--figures", action="store_true", help="write the contact sheets into docs/figures")


def suite(a: argparse.Namespace) -> dict:
    import mujoco
    import pybullet

    rows = bench(a.sizes, a.repeats)
    out = [[r["backend"], r["size"], r["ms_per_frame"], r["setup_ms"], r["simulate_s"], r["simulate_images_s"],
            r["overhead_x"]] for r in rows]
    return {"tables": [table(f"Rendered wipe rollouts (grid 9, 31 frames), median of {a.repeats}",
                             ["backend", "px", "ms / frame", "set-up ms", "simulate s", "simulate_images s",
                              "rendered / plain"], out)],
            "figures": list(figures()) if a.figures else [],
            "data": {"rows": rows, "mujoco": mujoco.__version__, "pybullet_api": pybullet.getAPIVersion()}}
