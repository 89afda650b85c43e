"""The cmaes suite: CMA-ES against softsbi on the real DiffCloud lift recordings at equal simulation budget.

For each recording: CMA-ES (Hansen's ``cma`` library, not our code) minimises a per-frame Chamfer metric over the
fit's own unit-cube parameter space (start at the centre, sigma 0.3), with the simulation budget of a default
``softsbi fit`` (4 rounds x 150 + 30 posterior rollouts = 630 simulations), through the fit's own simulation job
(same simulator, scenario, sensor model). With ``--softsbi`` (a default fit of the recording in ``--fits DIR/<r>``,
made where missing), softsbi's posterior-mean rollout and posterior predictive (the fit's evaluation samples with
their seeds) on the same metric, and the fit's prior; with ``--refine N``, ``softsbi fit --refine N`` on that fit:
the refined best fit's Chamfer over CMA-ES's best (both re-evaluated with ``--reevaluate`` fresh seeds) and whether
refining left the posterior unchanged (``report.json``'s posterior summaries and every round's stored ``q``).

Metrics (``--metric``), all on clouds seen through the fit's sensor model unless named ``full``:

* ``fit``: bidirectional Chamfer, mean over the fit's frames (``--frames auto``: the gripper at
  least 10 cm up) = ``report.json``'s ``chamfer_posterior_m`` (the headline);
* ``all``: bidirectional Chamfer, mean over every frame;
* ``one``: one-sided measured -> simulated Chamfer, mean over the fit's frames;
* ``full``: full clouds, every frame.
"""
from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

warnings.filterwarnings("ignore", message="Could not import matplotlib")

import cma  # noqa: E402

from softsbi.core.store import RunStore  # noqa: E402
from softsbi.perception.pointcloud import rollout_clouds  # noqa: E402
from softsbi.workflows.fit.run import FitConfig, fit_param_space, metric_sensor, observer_options  # noqa: E402
from softsbi.workflows.fit.jobs import JobItem, JobResult, SimContext, evaluation_seeds, simulate_job  # noqa: E402
from softsbi.workflows.measurement import load_recording  # noqa: E402

from benchmarks.runner import REPO, table  # noqa: E402

DATA = REPO.parent / "shared" / "data" / "diffcloud_lift"
METRICS = ("fit", "all", "one", "full")


def contexts(folder: Path) -> tuple[FitConfig, object, dict, SimContext, SimContext]:
    """The recording in ``folder``, the default fit's parameter space, sensor model and two worker contexts
    (the fit's sensor model, and full clouds): :func:`contexts_of` of :func:`load_recording`."""
    return contexts_of(load_recording(folder))


def contexts_of(rec) -> tuple[FitConfig, object, dict, SimContext, SimContext]:
    """:func:`contexts` for a :class:`~softsbi.core.types.Recording` already in memory (e.g. a simulated twin,
    ``cmaes_twin.py``)."""
    cfg = FitConfig(workers=1).resolved(rec)
    _, space = fit_param_space(cfg, rec.scenario)
    sensor = metric_sensor(cfg, rec.scenario)
    kw = dict(backend=cfg.backend, backend_options=cfg.backend_options, scenario=rec.scenario.to_json(), effects=[],
              observer=cfg.observer, observer_options=observer_options(cfg, rec.scenario), param_names=space.names,
              fixed={}, dense=rec.dense, n_dense=cfg.n_dense)
    return rec, space, sensor, SimContext(**kw, min_z=sensor["metric_min_z"]), SimContext(**kw, min_z=None)


def score(res: JobResult, metric: str, frames: list[int] | None) -> float:
    """The scalar ``metric`` (m) of one job result (``inf`` for a failed simulation)."""
    if res.chamfer is None:
        return float("inf")
    fr = slice(None) if frames is None else frames
    if metric == "one":
        return float(np.mean(res.chamfer_one_sided[fr]))
    if metric == "fit":
        return float(np.mean(res.chamfer[fr]))
    return float(np.mean(res.chamfer))  # all, full (the context decides what is seen)


def simulated_clouds(ctx: SimContext, theta: np.ndarray, seed: int, n: int | None = None
                     ) -> tuple[JobResult, list[np.ndarray] | None]:
    """One rollout through ``ctx``'s job with its vertices kept, and its surface clouds ``(n, 3)`` m per frame
    (``n`` points, default ``ctx.n_dense``, sampled with ``seed``); clouds None when the simulation failed."""
    res = simulate_job(SimContext(**{**ctx.__dict__, "keep_rollout": True}), JobItem(theta, seed))
    if res.chamfer is None:
        return res, None
    from softsbi.core.types import Rollout
    ro = Rollout(vertices=res.vertices, faces=res.faces, gripper=res.gripper,
                 times=np.asarray(ctx.scenario["times"]))
    return res, rollout_clouds(ro, ctx.n_dense if n is None else n, np.random.default_rng(seed))


def run(folder: Path, metric: str, budget: int, fit_dir: Path | None, seed: int, rec=None) -> dict:
    """CMA-ES on one recording and metric, then (with ``fit_dir``) softsbi's numbers on the same metric; ``rec``: the
    recording in memory instead of ``folder``'s (a twin; ``folder`` then only names it)."""
    t0 = time.perf_counter()
    rec, space, sensor, ctx_s, ctx_f = contexts(folder) if rec is None else contexts_of(rec)
    ctx = ctx_f if metric == "full" else ctx_s
    frames = sensor["metric_frames"]
    seeds = np.random.default_rng([seed, 17]).integers(0, 2**31 - 1, size=budget + 100)
    hist_u, hist_f, k = [], [], 0
    es = cma.CMAEvolutionStrategy(np.full(space.dim, 0.5), 0.3,
                                  {"bounds": [0, 1], "seed": seed + 1, "verbose": -9, "maxfevals": budget})
    while not es.stop() and k < budget:
        xs = es.ask()
        xs = xs[:budget - k]
        fs = []
        for x in xs:
            fs.append(score(simulate_job(ctx, JobItem(space.from_unit(np.asarray(x)), int(seeds[k]))), metric, frames))
            k += 1
        hist_u += [list(map(float, x)) for x in xs]
        hist_f += fs
        if len(xs) == es.popsize:
            es.tell(xs, [f if np.isfinite(f) else 1e3 for f in fs])
    cma_s = time.perf_counter() - t0
    b = int(np.argmin(hist_f))
    best_theta = space.from_unit(np.asarray(hist_u[b]))
    out = {"recording": folder.name, "metric": metric, "budget": budget, "simulations": k, "cma_seconds": cma_s,
           "cma_best_m": hist_f[b], "cma_best": space.as_dict(best_theta), "cma_best_unit": hist_u[b],
           "history_m": hist_f, "sensor": sensor}
    if fit_dir is not None and (fit_dir / "report.json").exists():
        out["softsbi"] = softsbi_side(fit_dir, space, ctx, metric, frames)
    out["seconds"] = time.perf_counter() - t0
    return out


def softsbi_side(fit_dir: Path, space, ctx: SimContext, metric: str, frames) -> dict:
    """A softsbi fit of the same recording on the same metric: posterior-mean rollout, posterior
    predictive (the fit's evaluation samples and seeds) and, where stored, the prior."""
    rep = json.loads((fit_dir / "report.json").read_text())
    store = RunStore.open(fit_dir / "run.zarr")
    pm = space.as_array(rep["posterior_mean"])
    pm_val = score(simulate_job(ctx, JobItem(pm, 0)), metric, frames)
    ev, attrs = store.read_group("evaluation")
    seeds = evaluation_seeds(int(store.config.get("seed", 0)), int(attrs["rounds"]), len(ev["theta"]))
    vals = [score(simulate_job(ctx, JobItem(th, int(s))), metric, frames) for th, s in zip(ev["theta"], seeds)]
    vals = [v for v in vals if np.isfinite(v)]
    d0 = store.round_data(0)
    ok = (d0["status"] == 0) & np.all(np.isfinite(d0["chamfer"]), axis=1)
    prior = {"fit": float(d0["chamfer"][ok][:, frames].mean(1).mean()) if frames else None,
             "all": float(d0["chamfer"][ok].mean(1).mean())}.get(metric)
    return {"posterior_mean": rep["posterior_mean"], "posterior_mean_rollout_m": pm_val,
            "posterior_predictive_m": float(np.mean(vals)), "n_predictive": len(vals), "prior_m": prior,
            "report_chamfer_prior_m": rep.get("chamfer_prior_m"),
            "report_chamfer_posterior_m": rep.get("chamfer_posterior_m"),
            "report_one_sided_posterior_m": rep.get("chamfer_posterior_one_sided_m"),
            "contraction": rep.get("contraction"), "wall_time_s": rep.get("wall_time_s")}


#: the posterior summaries of report.json that refining must leave as they were
POSTERIOR_KEYS = ("posterior_mean", "posterior_std", "posterior_q05", "posterior_q95", "posterior_median",
                  "contraction")


def _posterior_state(fit_dir: Path) -> dict:
    """What refining must not change: report.json's posterior summaries and every round's stored ``q``."""
    rep = json.loads((fit_dir / "report.json").read_text())
    store = RunStore.open(fit_dir / "run.zarr")
    return {"report": {k: rep.get(k) for k in POSTERIOR_KEYS},
            "q": [_flat(store.read_posterior(r)) for r in store.completed_rounds()]}


def _flat(q) -> np.ndarray:
    """A stored posterior's numbers, flattened: a mixture's arrays, or every array of an estimator's state."""
    if hasattr(q, "means"):
        return np.concatenate([q.weights.ravel(), q.means.ravel(), q.scale_tril.ravel()])
    arrays: list[np.ndarray] = []

    def walk(x) -> None:
        if isinstance(x, dict):
            for k in sorted(x):
                walk(x[k])
        elif isinstance(x, (list, tuple)):
            for v in x:
                walk(v)
        elif hasattr(x, "shape"):
            arrays.append(np.asarray(x, float).ravel())

    walk(q.state)
    return np.concatenate(arrays) if arrays else np.zeros(0)


def reevaluate(ctx: SimContext, theta: np.ndarray, metric: str, frames, seeds: list[int]) -> float:
    """Mean of ``metric`` over simulations at ``theta`` with fresh ``seeds`` (the seed changes the surface sampling
    of the Chamfer and the simulator's noise, so a minimum over noisy evaluations is optimistic)."""
    return float(np.mean([score(simulate_job(ctx, JobItem(theta, s)), metric, frames) for s in seeds]))


def refine_run(folder: Path, cma: dict, fit_dir: Path, n: int, workers: int, fit_args: list[str],
               n_reeval: int) -> dict:
    """``softsbi fit --refine n`` on ``fit_dir`` (a default fit of ``folder`` made first when it holds none) beside
    CMA-ES's stored result ``cma`` (:func:`run`) on the fit's headline metric."""
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "softsbi.cli", "fit", "--observed", str(folder), "--out", str(fit_dir),
           "--workers", str(workers), *fit_args]
    fit_s = None
    if not (fit_dir / "report.json").exists():
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        fit_s = time.perf_counter() - t0
    before = _posterior_state(fit_dir)
    plain = json.loads((fit_dir / "report.json").read_text()).get("best_fit") or {}
    t1 = time.perf_counter()
    subprocess.run(cmd + ["--refine", str(n)], check=True, stdout=subprocess.DEVNULL)
    refine_s = time.perf_counter() - t1
    after = _posterior_state(fit_dir)
    unchanged = before["report"] == after["report"] and len(before["q"]) == len(after["q"]) and all(
        np.array_equal(a, b) for a, b in zip(before["q"], after["q"]))
    rep = json.loads((fit_dir / "report.json").read_text())
    best = rep["best_fit"]
    rec, space, sensor, ctx_s, _ = contexts(folder)
    frames = sensor["metric_frames"]
    seeds = [int(x) for x in np.random.default_rng([56, 1]).integers(0, 2**31 - 1, size=n_reeval)]
    out = {"recording": folder.name, "refine": n, "cma_budget": cma["simulations"],
           "cma_best_m": cma["cma_best_m"], "best_fit_m": best["chamfer_m"],
           "best_fit_over_cma": best["chamfer_m"] / cma["cma_best_m"],
           "within_5pct": bool(best["chamfer_m"] <= 1.05 * cma["cma_best_m"]),
           "best_fit_before_refine_m": plain.get("chamfer_m"), "best_fit_source": best["source"],
           "best_fit": best["theta"], "cma_best": cma["cma_best"], "refine_info": best.get("refine"),
           "posterior_unchanged": bool(unchanged), "chamfer_posterior_m": rep.get("chamfer_posterior_m"),
           "chamfer_prior_m": rep.get("chamfer_prior_m"), "fit_seconds": fit_s, "refine_seconds": refine_s,
           "fit_simulations": rep.get("simulations"), "fit_wall_time_s": rep.get("wall_time_s")}
    if n_reeval:
        t2 = time.perf_counter()
        out["reevaluated"] = {"seeds": seeds,
                              "best_fit_m": reevaluate(ctx_s, space.as_array(best["theta"]), "fit", frames, seeds),
                              "cma_best_m": reevaluate(ctx_s, space.as_array(cma["cma_best"]), "fit", frames, seeds)}
        out["reevaluated"]["best_fit_over_cma"] = out["reevaluated"]["best_fit_m"] / out["reevaluated"]["cma_best_m"]
        out["reevaluate_seconds"] = time.perf_counter() - t2
    out["seconds"] = time.perf_counter() - t0
    return out


SECOND_REPEATS = ["lift_tan2", "lift_navy2", "lift_paper2", "lift_polka2", "lift_redblack2"]
FULL = {"recordings": SECOND_REPEATS, "budget": 630, "softsbi": True}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--recordings", nargs="+", default=["lift_tan2"], help="folders of --data")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--metric", choices=METRICS, default="fit")
    ap.add_argument("--budget", type=int, default=150, help="CMA-ES's simulations (a default fit: 4 x 150 + 30 = 630)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--softsbi", action="store_true", help="also score a default fit of each recording on the metric")
    ap.add_argument("--fits", type=Path, default=None, help="folder of the fits, one per recording (lift_tan2 -> "
                                                            "DIR/tan2; made where missing; default: a temporary one)")
    ap.add_argument("--fit-args", default="", help="extra `softsbi fit` arguments of the fits (quoted)")
    ap.add_argument("--workers", type=int, default=1, help="simulation workers of the fits")
    ap.add_argument("--refine", type=int, default=0, help="refine each fit with this many simulations and compare its "
                                                          "best fit with CMA-ES's (implies --softsbi)")
    ap.add_argument("--reevaluate", type=int, default=3, help="with --refine: fresh seeds re-evaluating both bests")


def suite(a: argparse.Namespace) -> dict:
    if (a.softsbi or a.refine) and a.fits is None:
        with tempfile.TemporaryDirectory() as tmp:
            return measure(a, Path(tmp))
    return measure(a, a.fits)


def default_fit(folder: Path, fit_dir: Path, workers: int, fit_args: list[str]) -> None:
    """A default ``softsbi fit`` of ``folder`` into ``fit_dir`` unless one is there."""
    if not (fit_dir / "report.json").exists():
        subprocess.run([sys.executable, "-m", "softsbi.cli", "fit", "--observed", str(folder), "--out", str(fit_dir),
                        "--workers", str(workers), *fit_args], check=True, stdout=subprocess.DEVNULL)


def measure(a: argparse.Namespace, fits: Path | None) -> dict:
    rows, refined, data = [], [], {}
    for name in a.recordings:
        fit_dir = None
        if fits is not None:
            fit_dir = fits / name.removeprefix("lift_")
            default_fit(a.data / name, fit_dir, a.workers, shlex.split(a.fit_args))
        res = run(a.data / name, a.metric, a.budget, fit_dir, a.seed)
        res.pop("history_m")
        s = res.get("softsbi") or {}
        cm = lambda v: None if v is None else round(100 * v, 2)  # noqa: E731
        pm, pp, prior = s.get("posterior_mean_rollout_m"), s.get("posterior_predictive_m"), s.get("prior_m")
        rows.append([name, res["simulations"], cm(res["cma_best_m"]), cm(pm), cm(pp), cm(prior),
                     None if pm is None else round(pm / res["cma_best_m"], 2),
                     round(res["cma_best"].get("yaw", float("nan")), 1), round(res["cma_best"]["friction"], 2),
                     round(res["cma_best"]["scale"], 3)])
        if a.refine:
            r = refine_run(a.data / name, res, fit_dir, a.refine, a.workers, shlex.split(a.fit_args), a.reevaluate)
            res["refine"] = r
            ree = r.get("reevaluated") or {}
            refined.append([name, a.refine, cm(r["best_fit_m"]), cm(r["cma_best_m"]), round(r["best_fit_over_cma"], 2),
                            None if not ree else round(ree["best_fit_over_cma"], 2), r["posterior_unchanged"]])
        data[name] = res
    tables = [table(f"Metric '{a.metric}' [cm]: CMA-ES's best of its simulations, softsbi's posterior-mean (PM) "
                    "rollout, posterior predictive and prior", ["recording", "CMA-ES simulations", "CMA-ES best",
                                                               "PM rollout", "posterior predictive", "prior",
                                                               "PM / CMA-ES", "CMA-ES yaw [deg]", "CMA-ES friction",
                                                               "CMA-ES scale [m]"], rows)]
    if refined:
        tables.append(table("softsbi's refined best fit against CMA-ES's best [cm]",
                            ["recording", "refine simulations", "best fit", "CMA-ES best", "ratio",
                             "ratio, re-evaluated", "posterior unchanged"], refined))
    return {"tables": tables, "data": data}
