"""Throughput of softsbi's executors on mujoco-flex lift simulations (issue 7).

Usage::

    nice -n 15 python benchmarks/bench_executors.py [--observed ../shared/data/diffcloud_lift/lift_tan]
        [--n 24] [--modes local1 local2 bare2 ray2] [--json out.json]

For each mode, the workers are started and warmed up first (one simulation each, so
imports and plugin loading are not timed), then ``--n`` prior draws of the lift (the real
recording's scenario and dense clouds, so each job also computes its Chamfer distance, as in
a fit) are simulated and timed. Modes: ``localW`` = softsbi's LocalExecutor with W worker
processes (a pool even for W=1), ``bareW`` = a bare ``multiprocessing.Pool(W)`` (spawn,
``imap_unordered``, chunksize 1) running the same ``simulate_job``, ``rayW`` = RayExecutor
with W workers on a local Ray. Prints a Markdown table (simulations/s, speed-up vs local1,
peak RSS per worker) and the machine load (``os.getloadavg``).
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import time
from pathlib import Path

import numpy as np

from softsbi.workflows.fit import FitConfig, SimContext, fit_param_space, observer_options, simulate_job

_CTX = None


def _init(ctx):
    global _CTX
    _CTX = ctx
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def _call(item):
    return simulate_job(_CTX, item)


def _peak_rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def _ray_peak_rss(ctx, item):
    import resource
    simulate_job(ctx, item)
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, os.getpid()


def build(observed: str, n: int, seed: int = 0):
    from softsbi.workflows.measurement import load_recording
    meas = load_recording(Path(observed), n_points=64, seed=seed)
    cfg = FitConfig(min_height=0.01)
    _, space = fit_param_space(cfg, meas.scenario)
    ctx = SimContext(backend=cfg.backend, backend_options={}, scenario=meas.scenario.to_json(), effects=[],
                     observer=cfg.observer, observer_options=observer_options(cfg, meas.scenario),
                     param_names=space.names, fixed={}, dense=np.asarray(meas.dense), n_dense=cfg.n_dense)
    rng = np.random.default_rng(seed)
    theta = space.from_unit(rng.random((n, space.dim)))
    return ctx, [(theta[i], int(1000 + i)) for i in range(n)]


def run_mode(mode: str, ctx, items) -> dict:
    kind, w = mode.rstrip("0123456789"), int(mode[len(mode.rstrip("0123456789")):])
    warm = items[:w]
    out = {"mode": mode, "workers": w}
    if kind == "bare":
        with mp.get_context("spawn").Pool(w, initializer=_init, initargs=(ctx,)) as pool:
            list(pool.imap_unordered(_call, warm, chunksize=1))
            t0 = time.perf_counter()
            res = list(pool.imap_unordered(_call, items, chunksize=1))
            out["seconds"] = time.perf_counter() - t0
            out["peak_rss_mb"] = max(_peak_rss_mb(p.pid) for p in pool._pool)  # noqa: SLF001
    elif kind == "local":
        from softsbi.executors.local import LocalExecutor
        ex = LocalExecutor(workers=w, in_process=False)
        try:
            list(ex.map_unordered(simulate_job, warm, context=ctx))
            t0 = time.perf_counter()
            res = [r for _, r in ex.map_unordered(simulate_job, items, context=ctx)]
            out["seconds"] = time.perf_counter() - t0
            out["peak_rss_mb"] = max(_peak_rss_mb(p) for p in ex.worker_pids())
        finally:
            ex.close()
    elif kind == "ray":
        import ray
        from softsbi.executors.ray_executor import RayExecutor
        ray.init(num_cpus=w, include_dashboard=False, log_to_driver=False, logging_level="warning")
        try:
            ex = RayExecutor(workers=w)
            list(ex.map_unordered(simulate_job, warm, context=ctx))
            t0 = time.perf_counter()
            res = [r for _, r in ex.map_unordered(simulate_job, items, context=ctx)]
            out["seconds"] = time.perf_counter() - t0
            rss = [r for _, r in ex.map_unordered(_ray_peak_rss, warm * 2, context=ctx)]
            out["peak_rss_mb"] = max(r[0] for r in rss if not isinstance(r, BaseException))
        finally:
            ray.shutdown()
    else:
        raise SystemExit(f"unknown mode {mode!r}; use localW, bareW or rayW")
    bad = [r for r in res if isinstance(r, BaseException)]
    out.update(n=len(items), failed=len(bad), ok=sum(1 for r in res if not isinstance(r, BaseException)
                                                       and r["status"] == 0),
               sims_per_s=len(items) / out["seconds"], load=os.getloadavg())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--observed", default=str(Path(__file__).resolve().parents[1].parent / "shared" / "data"
                                              / "diffcloud_lift" / "lift_tan"))
    ap.add_argument("--n", type=int, default=24, help="simulations per mode")
    ap.add_argument("--modes", nargs="+", default=["local1", "local2", "bare2", "ray2"])
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    ctx, items = build(args.observed, args.n)
    rows = []
    for m in args.modes:
        r = run_mode(m, ctx, items)
        rows.append(r)
        print(json.dumps(r), flush=True)
    base = {r["mode"]: r for r in rows}
    print("\n| mode | workers | sims | s | sims/s | vs local1 | peak RSS/worker (MB) | load (1/5/15 min) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        ratio = r["sims_per_s"] / base["local1"]["sims_per_s"] if "local1" in base else float("nan")
        load = "/".join(f"{x:.1f}" for x in r["load"])
        print(f"| {r['mode']} | {r['workers']} | {r['n']} ({r['ok']} ok) | {r['seconds']:.1f} | "
              f"{r['sims_per_s']:.2f} | {ratio:.2f}x | {r['peak_rss_mb']:.0f} | {load} |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
