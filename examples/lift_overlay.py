"""Overlay a DiffCloud lift recording on the mujoco-flex rollout (top + side view PNGs).

Usage::

    python examples/lift_overlay.py [RECORDING_DIR] [OUT_DIR] [RUN_DIR]

Defaults: ``../shared/data/diffcloud_lift/lift_tan`` beside the repository, ``OUT_DIR = overlays``.
Writes ``<recording>_frame00.png`` (the partial first frame against the flat initial cloth) and
``<recording>_frame24.png`` (the hanging cloth, the most informative frame for size/placement),
simulated at the midpoint of the prior (placement ``yaw`` 0: DiffCloud's diamond). With ``RUN_DIR``
(a ``softsbi fit`` output of the same recording) it simulates at that fit's posterior mean instead
(inferred placement included) and names the files ``..._posterior.png``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.report import plot_scenario_overlay as overlay_png
from softsbi.scenarios.builtin import load_recording, lift_scenario


def main(argv: list[str]) -> None:
    repo = Path(__file__).resolve().parents[1]
    rec = Path(argv[1]) if len(argv) > 1 else repo.parent / "shared" / "data" / "diffcloud_lift" / "lift_tan"
    out = Path(argv[2]) if len(argv) > 2 else repo / "overlays"
    run = Path(argv[3]) if len(argv) > 3 else None
    scenario = lift_scenario(rec)
    sim = MujocoFlex()
    space = sim.param_space(scenario)
    if run is None:
        theta, label, suffix = space.midpoint(), "prior midpoint", ""
    else:
        report = json.loads((run / "report.json").read_text())
        theta = {n: float(v) for n, v in report["posterior_mean"].items() if n in space.names}
        theta = {**space.midpoint(), **theta}
        label = "posterior mean" + (f", yaw {theta['yaw']:+.0f} deg" if "yaw" in theta else "")
        suffix = "_posterior"
    rollout = sim.simulate(scenario, theta)
    clouds = load_recording(rec)
    for frame in (0, len(clouds) - 1):
        p = overlay_png(scenario, rollout, clouds[frame], out / f"{rec.name}_frame{frame:02d}{suffix}.png",
                        frame=frame, title=f"{rec.name} frame {frame}: measured (grey) vs mujoco-flex at {label} (blue)")
        print(p)


if __name__ == "__main__":
    main(sys.argv)
