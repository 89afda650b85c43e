"""The executors suite: throughput of softsbi's executors on mujoco-flex lift simulations.

For each mode, the workers are started and warmed up first (one simulation each, so
imports and plugin loading are not timed), then ``--n`` prior draws of the lift (the real
recording's scenario and dense clouds, so each job also computes its Chamfer distance, as in
a fit) are simulated and timed. Modes: ``localW`` = softsbi's LocalExecutor with W worker
processes (a pool even for W=1), ``bareW`` = a bare ``multiprocessing.Pool(W)`` (spawn,
``imap_unordered``, chunksize 1) running the same ``simulate_job``, ``rayW`` = RayExecutor
with W workers on a local Ray (skipped when ray is not installed). Reports simulations/s, the speed-up
over local1, the peak RSS per worker and the machine load (``os.getloadavg``) after each mode.
"""
from __future__ import annotations

import argparse
import importlib.util
import multiprocessing as mp
import os
import time
from pathlib import Path

import numpy as np

from softsbi.workflows.fit.run import (FitConfig, JobItem, SimContext, fit_param_space, observer_options,
                                       simulate_job)

from benchmarks.runner import REPO, table

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
    return ctx, [JobItem(theta[i], int(1000 + i)) for i in range(n)]


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
            out["peak_rss_mb"] = max(_peak_rss_mb(p.pid) for p in pool._pool)
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
                                                       and r.status == 0),
               sims_per_s=len(items) / out["seconds"], load=os.getloadavg())
    return out


FULL = {"n": 240}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--observed", type=Path, default=REPO.parent / "shared" / "data" / "diffcloud_lift" / "lift_tan",
                    help="the recording whose scenario and dense clouds the jobs use")
    ap.add_argument("--n", type=int, default=24, help="simulations per mode")
    ap.add_argument("--modes", nargs="+", default=["local1", "local2", "bare2", "ray2"])


def suite(a: argparse.Namespace) -> dict:
    ctx, items = build(str(a.observed), a.n)
    rows, notes = [], []
    for m in a.modes:
        if m.startswith("ray") and importlib.util.find_spec("ray") is None:
            notes.append(f"{m} skipped: ray is not installed (pip install 'softsbi[ray]').")
            continue
        rows.append(run_mode(m, ctx, items))
    base = {r["mode"]: r for r in rows}
    out = []
    for r in rows:
        ratio = r["sims_per_s"] / base["local1"]["sims_per_s"] if "local1" in base else None
        out.append([r["mode"], r["workers"], r["n"], r["ok"], round(r["seconds"], 1), round(r["sims_per_s"], 2),
                    None if ratio is None else round(ratio, 2), round(r["peak_rss_mb"]),
                    "/".join(f"{x:.1f}" for x in r["load"])])
    return {"tables": [table(f"{a.n} prior draws of the {a.observed.name} scenario on mujoco-flex per mode",
                             ["mode", "workers", "simulations", "ok", "s", "simulations/s", "vs local1",
                              "peak RSS/worker (MB)", "load after (1/5/15 min)"], out)],
            "notes": notes, "data": {"rows": rows}}
