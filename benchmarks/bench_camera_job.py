"""Per-rollout cost of a camera fit's simulation job (issue 17: render each frame once).

Times :func:`softsbi.workflows.jobs.simulate_job` in this process (1 worker) on a ``FitConfig(sensor="camera")``
context of a DiffCloud lift recording (defaults: lift_tan, mujoco-flex grid 9, 25 frames, 64 observed points,
600 dense points), ``--n`` prior draws with seeds ``0..n-1``, after one warm-up job; counts the virtual
sensor's renders (``VirtualDepthSensor._camera_points`` calls) per rollout and prints a SHA-256 of every
result's observation ``x`` and per-frame Chamfer, so two versions of the code can be checked bit-identical.

    python benchmarks/bench_camera_job.py --recording lift_tan --n 10 --repeat 3
"""
from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import numpy as np
import torch

from softsbi.perception.depth_sensor import VirtualDepthSensor
from softsbi.workflows.fit import FitConfig, fit_param_space, metric_sensor, observer_options
from softsbi.workflows.jobs import SimContext, simulate_job
from softsbi.workflows.measurement import load_recording

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "diffcloud_lift"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recording", default="lift_tan")
    ap.add_argument("--grid", type=int, default=9)
    ap.add_argument("--n", type=int, default=10, help="timed rollouts per repeat")
    ap.add_argument("--repeat", type=int, default=3, help="repeats of the n rollouts (the median is reported)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    meas = load_recording(DATA / args.recording, n_points=64, seed=0)
    cfg = FitConfig(sensor="camera", workers=1, backend_options={"grid": args.grid}).resolved(meas)
    _, inferred = fit_param_space(cfg, meas.scenario)
    sens = metric_sensor(cfg, meas.scenario)
    ctx = SimContext(backend=cfg.backend, backend_options=cfg.backend_options, scenario=meas.scenario.to_json(),
                     effects=[], observer=cfg.observer, observer_options=observer_options(cfg, meas.scenario),
                     param_names=inferred.names, fixed={}, dense=meas.dense, n_dense=cfg.n_dense,
                     min_z=sens["metric_min_z"], camera=sens["metric_camera"])
    theta = inferred.from_unit(np.random.default_rng(0).random((args.n, inferred.dim)))
    renders = [0]
    inner = VirtualDepthSensor._camera_points

    def counted(self, *a, **k):
        renders[0] += 1
        return inner(self, *a, **k)

    VirtualDepthSensor._camera_points = counted  # type: ignore[method-assign]
    simulate_job(ctx, (theta[0], 0))  # warm-up: engine build, sensor from JSON
    times, digest = [], None
    for _ in range(args.repeat):
        renders[0] = 0
        h = hashlib.sha256()
        t0 = time.perf_counter()
        res = [simulate_job(ctx, (theta[i], i)) for i in range(args.n)]
        times.append((time.perf_counter() - t0) / args.n)
        for r in res:
            assert r["status"] == 0, r["reason"]
            h.update(np.ascontiguousarray(r["x"]).tobytes())
            h.update(np.ascontiguousarray(r["chamfer"]).tobytes())
            h.update(np.ascontiguousarray(r["chamfer_one_sided"]).tobytes())
        digest = h.hexdigest() if digest is None else digest
        assert digest == h.hexdigest(), "results differ between repeats"
    T = len(meas.dense)
    print(json.dumps({"recording": args.recording, "grid": args.grid, "frames": T, "rollouts": args.n,
                      "seconds_per_rollout": [round(t, 4) for t in times],
                      "median_s_per_rollout": round(float(np.median(times)), 4),
                      "renders_per_frame": renders[0] / (args.n * T), "sha256": digest}))


if __name__ == "__main__":
    main()
