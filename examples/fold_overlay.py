"""Overlay a DiffCloud fold recording on the fold scenario's rollouts (first and middle frames).

Usage::

    python examples/fold_overlay.py [RECORDING_DIR] [OUT_DIR] [RUN_DIR]

Defaults: ``../shared/data/diffcloud_fold/fold_tan`` beside the repository, ``OUT_DIR = docs/figures``.
Loads the recording through the generic path (the DiffCloud importer with ``examples/fold.yaml``),
simulates the scenario on mujoco-flex at the prior midpoint and writes
``fold_overlay_<recording>_frameNN.png`` for frames 0 and 12 (top and side views, the palette of
:func:`softsbi.report.plot_scenario_overlay`). With ``RUN_DIR`` (a ``softsbi fit`` of the same
recording) it simulates at that fit's posterior mean (inferred yaw included) and adds ``_posterior``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import softsbi
from softsbi.report import plot_scenario_overlay
from softsbi.workflows.measurement import diffcloud_recording, recording_from_meta


def main(argv: list[str]) -> None:
    repo = Path(__file__).resolve().parents[1]
    rec = Path(argv[1]) if len(argv) > 1 else repo.parent / "shared" / "data" / "diffcloud_fold" / "fold_tan"
    out = Path(argv[2]) if len(argv) > 2 else repo / "docs" / "figures"
    meta, clouds = diffcloud_recording(rec, repo / "examples" / "fold.yaml")
    clouds = [c * 0.35 for c in clouds]  # the recording's transform: simulator units -> metres
    meas = recording_from_meta(meta, clouds, rec, n_points=64, source=str(rec))
    sc = meas.scenario
    theta, label, suffix = None, "the prior midpoint", ""
    if len(argv) > 3:
        rep = json.loads((Path(argv[3]) / "report.json").read_text())
        theta = rep["posterior_mean"]
        label, suffix = f"the posterior mean (yaw {theta.get('yaw', 0.0):+.0f} deg)", "_posterior"
    ro = softsbi.simulate(sc, theta, backend="mujoco-flex")
    print(f"{rec.name}: rollout {'ok' if ro.ok else ro.reason}")
    for frame in (0, sc.n_frames // 2):
        p = plot_scenario_overlay(sc, ro, clouds[frame], out / f"fold_overlay_{rec.name}_frame{frame:02d}{suffix}.png",
                                  frame=frame, title=f"{rec.name} frame {frame}: measured (grey) vs mujoco-flex "
                                                     f"fold at {label} (blue)")
        print(p)


if __name__ == "__main__":
    main(sys.argv)
