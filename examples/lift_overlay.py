"""Overlay a DiffCloud lift recording on the mujoco-flex rollout (top + side view PNGs).

Usage::

    python examples/lift_overlay.py [RECORDING_DIR] [OUT_DIR]

Defaults: ``../shared/data/diffcloud_lift/lift_tan`` beside the repository, ``OUT_DIR = overlays``.
Writes ``<recording>_frame00.png`` (the partial first frame against the flat initial cloth) and
``<recording>_frame24.png`` (the hanging cloth, the most informative frame for size/placement),
simulated at the midpoint of the prior.
"""
from __future__ import annotations

import sys
from pathlib import Path

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.backends.scenarios import load_recording, lift_scenario, overlay_png


def main(argv: list[str]) -> None:
    repo = Path(__file__).resolve().parents[1]
    rec = Path(argv[1]) if len(argv) > 1 else repo.parent / "shared" / "data" / "diffcloud_lift" / "lift_tan"
    out = Path(argv[2]) if len(argv) > 2 else repo / "overlays"
    scenario = lift_scenario(rec)
    sim = MujocoFlex()
    theta = sim.param_space(scenario).midpoint()
    rollout = sim.simulate(scenario, theta)
    clouds = load_recording(rec)
    for frame in (0, len(clouds) - 1):
        p = overlay_png(scenario, rollout, clouds[frame], out / f"{rec.name}_frame{frame:02d}.png", frame=frame,
                        title=f"{rec.name} frame {frame}: real (blue) vs mujoco-flex at prior midpoint (red)")
        print(p)


if __name__ == "__main__":
    main(sys.argv)
