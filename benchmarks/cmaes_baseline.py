"""CMA-ES baseline on the real DiffCloud lift recordings (issue 17).

For one recording: CMA-ES (Hansen's ``cma`` library, not our code) minimises a per-frame Chamfer
metric over the fit's own unit-cube parameter space, with the simulation budget of a default
``softsbi fit`` (4 rounds x 150 + 30 posterior rollouts = 630 simulations), through the fit's own
simulation job (same simulator, scenario, sensor model). It then reports

* CMA-ES's best value and parameters (``yaw`` especially);
* softsbi's posterior-mean rollout and posterior predictive (the fit's 30 evaluation samples with
  their seeds) of a fit of the same recording, on the same metric, and the fit's prior;
* the hanging frames' evidence for the placement yaw: the orientation of the hanging sheet (the
  principal horizontal axis of the last :data:`HANGING` frames' clouds, seen through the sensor
  model) of the recording vs the simulation at CMA-ES's best and at the posterior mean, and the yaw
  that aligns them (a sweep of ``yaw`` with the other parameters at CMA-ES's best).

Metrics (``--metric``), all on clouds seen through the fit's sensor model unless named ``full``:

* ``fit``: bidirectional Chamfer, mean over the fit's frames (``--frames auto``: the gripper at
  least 10 cm up) = ``report.json``'s ``chamfer_posterior_m`` (the headline);
* ``all``: bidirectional Chamfer, mean over every frame;
* ``one``: one-sided measured -> simulated Chamfer, mean over the fit's frames;
* ``full``: the metric before issue 17: full clouds, every frame.

`cma` is a core dependency of softsbi (`fit --refine`).

With ``--refine N`` (issue 56: a best fit beside the posterior), per recording in the same run: the CMA-ES
baseline above (stored results are reused), then ``softsbi fit --refine N`` on the fit of ``--fits DIR/<r>``
(a default fit is made first where the folder holds none), and the JSON the criterion needs: the refined best
fit's Chamfer over CMA-ES's best (both the minimum of their own noisy evaluations, and both re-evaluated with
``--reevaluate`` fresh seeds), whether the posterior is unchanged by refining (``report.json``'s posterior
summaries and every round's stored ``q``), and the seconds spent.

Usage:
    python benchmarks/cmaes_baseline.py --recording lift_tan2 --metric fit --fit runs/real17/tan2 \
        --out runs/cmaes17
    python benchmarks/cmaes_baseline.py --table runs/cmaes17 [--fits runs/real17]
    python benchmarks/cmaes_baseline.py --recording lift_tan2,lift_navy2,lift_paper2,lift_polka2,lift_redblack2 \
        --refine 150 --fits runs/real56 --out runs/cmaes56 --workers 2
"""
from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

warnings.filterwarnings("ignore", message="Could not import matplotlib")

import cma  # noqa: E402

from softsbi.core.store import RunStore  # noqa: E402
from softsbi.perception.pointcloud import rollout_clouds, sensor_view  # noqa: E402
from softsbi.workflows.fit import FitConfig, fit_param_space, metric_sensor, observer_options  # noqa: E402
from softsbi.workflows.jobs import SimContext, evaluation_seeds, simulate_job  # noqa: E402
from softsbi.workflows.measurement import load_recording  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared/data/diffcloud_lift"
METRICS = ("fit", "all", "one", "full")
#: the last frames, where the cloth hangs clear of the table (the yaw's evidence)
HANGING = 5
#: yaw sweep (deg) for the hanging frames' evidence
YAW_GRID = np.linspace(-45, 45, 13)


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


def score(res: dict, metric: str, frames: list[int] | None) -> float:
    """The scalar ``metric`` (m) of one job result (``inf`` for a failed simulation)."""
    if res["chamfer"] is None:
        return float("inf")
    fr = slice(None) if frames is None else frames
    if metric == "one":
        return float(np.mean(res["chamfer_one_sided"][fr]))
    if metric == "fit":
        return float(np.mean(res["chamfer"][fr]))
    return float(np.mean(res["chamfer"]))  # all, full (the context decides what is seen)


def hanging_axis_deg(clouds: np.ndarray | list, min_z: float | None) -> float:
    """Orientation (deg, in [-90, 90)) of the hanging sheet: the principal axis of the horizontal (x, y)
    coordinates of the last :data:`HANGING` clouds, each seen through the sensor model, pooled."""
    pts = np.concatenate([sensor_view(np.asarray(c, float), min_z)[:, :2] - sensor_view(np.asarray(c, float),
                                                                                        min_z)[:, :2].mean(0)
                          for c in clouds[-HANGING:]])
    w, v = np.linalg.eigh(np.cov(pts.T))
    a = np.degrees(np.arctan2(v[1, -1], v[0, -1]))
    return float((a + 90) % 180 - 90)


def yaw_sweep(ctx: SimContext, space, theta: np.ndarray, real_axis: float) -> dict:
    """The hanging frames' evidence for the yaw, with the other parameters at ``theta``: each yaw of
    :data:`YAW_GRID` simulated once; the yaw whose hanging sheet is oriented like the recording's
    (:func:`aligning_yaw`) and the yaw of the lowest Chamfer over the last :data:`HANGING` frames."""
    if "yaw" not in space.names:
        return {"sweep": [], "yaw_aligning_axis": None, "yaw_best_hanging_chamfer": None}
    iy = space.names.index("yaw")
    sweep = []
    for y in YAW_GRID:
        th = np.array(theta, float)
        th[iy] = y
        r, ax = rollout_axis(ctx, th, 0)
        hang = float(np.mean(r["chamfer"][-HANGING:])) if r["chamfer"] is not None else None
        sweep.append({"yaw": float(y), "axis_deg": ax, "hanging_chamfer_m": hang,
                      "mismatch_deg": None if ax is None else wrap90(ax - real_axis)})
    okc = [s for s in sweep if s["hanging_chamfer_m"] is not None]
    return {"sweep": sweep, "yaw_aligning_axis": aligning_yaw(sweep),
            "yaw_best_hanging_chamfer": min(okc, key=lambda s: s["hanging_chamfer_m"])["yaw"] if okc else None}


def aligning_yaw(sweep: list[dict]) -> float | None:
    """The yaw (deg) at which the simulated hanging sheet's orientation matches the recording's: the
    zero of the sweep's axis mismatch, linearly interpolated between neighbouring yaws (a sign change
    across a jump of 60 deg or more is the +-90 deg wrap, not a match); the smallest mismatch's yaw when
    nothing crosses zero."""
    ok = [s for s in sweep if s["mismatch_deg"] is not None]
    if not ok:
        return None
    best = min(ok, key=lambda s: abs(s["mismatch_deg"]))
    zeros = []
    for a, b in zip(ok, ok[1:]):
        ma, mb = a["mismatch_deg"], b["mismatch_deg"]
        if ma == 0:
            zeros.append((0.0, a["yaw"]))
        elif ma * mb < 0 and abs(ma - mb) < 60:
            zeros.append((min(abs(ma), abs(mb)), a["yaw"] + (b["yaw"] - a["yaw"]) * ma / (ma - mb)))
    return float(min(zeros)[1]) if zeros else float(best["yaw"])


def wrap90(a: float) -> float:
    """An axis difference (deg) wrapped into [-90, 90)."""
    return float((a + 90) % 180 - 90)


def simulated_clouds(ctx: SimContext, theta: np.ndarray, seed: int, n: int | None = None
                     ) -> tuple[dict, list[np.ndarray] | None]:
    """One rollout through ``ctx``'s job with its vertices kept, and its surface clouds ``(n, 3)`` m per frame
    (``n`` points, default ``ctx.n_dense``, sampled with ``seed``); clouds None when the simulation failed."""
    res = simulate_job(SimContext(**{**ctx.__dict__, "keep_rollout": True}), (theta, seed))
    if res["chamfer"] is None:
        return res, None
    from softsbi.core.types import Rollout
    ro = Rollout(vertices=res["vertices"], faces=res["faces"], gripper=res["gripper"],
                 times=np.asarray(ctx.scenario["times"]))
    return res, rollout_clouds(ro, ctx.n_dense if n is None else n, np.random.default_rng(seed))


def rollout_axis(ctx: SimContext, theta: np.ndarray, seed: int) -> tuple[dict, float | None]:
    """One rollout (with its vertices) and its hanging-sheet orientation (deg)."""
    res, clouds = simulated_clouds(ctx, theta, seed)
    return res, None if clouds is None else hanging_axis_deg(clouds, ctx.min_z)


def run(folder: Path, metric: str, budget: int, fit_dir: Path | None, seed: int, rec=None) -> dict:
    """CMA-ES on one recording and metric, then softsbi's numbers on the same metric and the yaw evidence;
    ``rec``: the recording in memory instead of ``folder``'s (a twin; ``folder`` then only names it)."""
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
            fs.append(score(simulate_job(ctx, (space.from_unit(np.asarray(x)), int(seeds[k]))), metric, frames))
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
           "history_m": hist_f, "sensor": sensor, "yaw_bounds": [space["yaw"].low, space["yaw"].high]
           if "yaw" in space.names else None}
    # hanging frames' evidence for the yaw
    real_axis = hanging_axis_deg(list(rec.dense), ctx_s.min_z)
    res_b, ax_b = rollout_axis(ctx_s, best_theta, int(seeds[b]))
    sw = yaw_sweep(ctx_s, space, best_theta, real_axis)
    out["evidence"] = {"real_axis_deg": real_axis, "cma_axis_deg": ax_b,
                       "cma_axis_mismatch_deg": None if ax_b is None else wrap90(ax_b - real_axis),
                       "yaw_aligning_axis": sw["yaw_aligning_axis"],
                       "yaw_best_hanging_chamfer": sw["yaw_best_hanging_chamfer"], "sweep": sw["sweep"],
                       "nominal": yaw_sweep(ctx_s, space, space.from_unit(np.full(space.dim, 0.5)), real_axis)}
    if fit_dir is not None and (fit_dir / "report.json").exists():
        out["softsbi"] = softsbi_side(fit_dir, space, ctx, metric, frames, real_axis, ctx_s)
    out["seconds"] = time.perf_counter() - t0
    return out


def softsbi_side(fit_dir: Path, space, ctx: SimContext, metric: str, frames, real_axis: float,
                 ctx_s: SimContext) -> dict:
    """A softsbi fit of the same recording on the same metric: posterior-mean rollout, posterior
    predictive (the fit's evaluation samples and seeds) and, where stored, the prior."""
    rep = json.loads((fit_dir / "report.json").read_text())
    store = RunStore.open(fit_dir / "run.zarr")
    pm = space.as_array(rep["posterior_mean"])
    res_pm, ax_pm = rollout_axis(ctx_s, pm, 0)
    pm_val = score(simulate_job(ctx, (pm, 0)), metric, frames)
    ev, attrs = store.read_group("evaluation")
    seeds = evaluation_seeds(int(store.config.get("seed", 0)), int(attrs["rounds"]), len(ev["theta"]))
    vals = [score(simulate_job(ctx, (th, int(s))), metric, frames) for th, s in zip(ev["theta"], seeds)]
    vals = [v for v in vals if np.isfinite(v)]
    d0 = store.round_data(0)
    ok = (d0["status"] == 0) & np.all(np.isfinite(d0["chamfer"]), axis=1)
    prior = {"fit": float(d0["chamfer"][ok][:, frames].mean(1).mean()) if frames else None,
             "all": float(d0["chamfer"][ok].mean(1).mean())}.get(metric)
    return {"fit": str(fit_dir), "posterior_mean": rep["posterior_mean"], "posterior_mean_rollout_m": pm_val,
            "posterior_predictive_m": float(np.mean(vals)), "n_predictive": len(vals), "prior_m": prior,
            "report_chamfer_prior_m": rep.get("chamfer_prior_m"),
            "report_chamfer_posterior_m": rep.get("chamfer_posterior_m"),
            "report_one_sided_posterior_m": rep.get("chamfer_posterior_one_sided_m"),
            "posterior_mean_axis_mismatch_deg": None if ax_pm is None else wrap90(ax_pm - real_axis),
            "contraction": rep.get("contraction"), "wall_time_s": rep.get("wall_time_s")}


def table(folder: Path) -> None:
    """Markdown table of every ``<recording>_<metric>.json`` in ``folder``."""
    rows = [json.loads(f.read_text()) for f in sorted(folder.glob("*_*.json"))]
    print("| recording | metric | CMA-ES best [cm] | softsbi posterior-mean rollout [cm] | softsbi posterior "
          "predictive [cm] | prior [cm] | post. pred. / prior | PM rollout / CMA best | yaw CMA-ES / posterior "
          "mean [deg] | hanging evidence, nominal cloth: axis / Chamfer [deg] | at CMA's other params: axis / "
          "Chamfer [deg] | CMA friction, scale |")
    print("|" + "---|" * 12)
    f = lambda v: "n/a" if v is None else f"{v * 100:.2f}"  # noqa: E731
    g = lambda v: "n/a" if v is None else f"{v:+.1f}"  # noqa: E731
    for r in rows:
        s = r.get("softsbi") or {}
        ev = r["evidence"]
        nom = ev.get("nominal") or {}
        ratio = (s["posterior_predictive_m"] / s["prior_m"]) if s.get("prior_m") else None
        pm_ratio = s["posterior_mean_rollout_m"] / r["cma_best_m"] if s else None
        print(f"| {r['recording']} | {r['metric']} | {f(r['cma_best_m'])} | {f(s.get('posterior_mean_rollout_m'))} | "
              f"{f(s.get('posterior_predictive_m'))} | {f(s.get('prior_m'))} | "
              f"{'n/a' if ratio is None else f'{ratio:.2f}'} | {'n/a' if pm_ratio is None else f'{pm_ratio:.2f}'} | "
              f"{g(r['cma_best'].get('yaw'))} / {g(s.get('posterior_mean', {}).get('yaw'))} | "
              f"{g(nom.get('yaw_aligning_axis'))} / {g(nom.get('yaw_best_hanging_chamfer'))} | "
              f"{g(ev['yaw_aligning_axis'])} / {g(ev['yaw_best_hanging_chamfer'])} | "
              f"{r['cma_best']['friction']:.2f}, {r['cma_best']['scale']:.3f} |")


def overlay(folder: Path, result: Path, png: Path, frames=(0, 8, 14, 24)) -> None:
    """Figure: the recording's cloud (seen through the sensor model) and the simulated clouds at
    CMA-ES's best and at softsbi's posterior mean (each seen through the same model), top view (x, y)
    and side view (x, z) at a few frames; the grey points are simulated cloth the sensor does not see."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    res = json.loads(result.read_text())
    rec, space, sensor, ctx_s, _ = contexts(folder)
    thetas = {"CMA-ES best": space.as_array(res["cma_best"])}
    if res.get("softsbi"):
        thetas["softsbi posterior mean"] = space.as_array(res["softsbi"]["posterior_mean"])
    min_z = ctx_s.min_z
    sims = {}
    for k, th in thetas.items():
        sims[k] = simulated_clouds(ctx_s, th, 0)[1]
    fig, axes = plt.subplots(2, len(frames), figsize=(4.2 * len(frames), 8.4))
    cols = {"CMA-ES best": "tab:red", "softsbi posterior mean": "tab:blue"}
    for j, t in enumerate(frames):
        real = sensor_view(rec.dense[t], min_z)
        for i, (a, b) in enumerate(((0, 1), (0, 2))):
            ax = axes[i, j]
            for k, c in sims.items():
                seen = c[t][:, 2] > min_z if min_z is not None else np.ones(len(c[t]), bool)
                ax.scatter(c[t][~seen, a], c[t][~seen, b], s=3, c="0.75")
                ax.scatter(c[t][seen, a], c[t][seen, b], s=4, c=cols[k], alpha=0.5,
                           label=f"{k} (yaw {thetas[k][space.names.index('yaw')]:+.0f} deg)")
            ax.scatter(real[:, a], real[:, b], s=4, c="k", alpha=0.6, label="recording (sensor view)")
            ax.set_aspect("equal")
            ax.set_xlabel("x [m]", fontsize=11)
            ax.set_ylabel(("y" if b == 1 else "z") + " [m]", fontsize=11)
            ax.set_title(f"frame {t} ({'top' if b == 1 else 'side'} view)", fontsize=12)
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=9, loc="best", markerscale=3)
    fig.suptitle(f"{folder.name}: metric '{res['metric']}' (grey: simulated cloth the sensor model does not see)",
                 fontsize=13)
    fig.tight_layout()
    fig.savefig(png, dpi=90)


#: the posterior summaries of report.json that refining must leave as they were
POSTERIOR_KEYS = ("posterior_mean", "posterior_std", "posterior_q05", "posterior_q95", "posterior_median", "contraction")


def _posterior_state(fit_dir: Path) -> dict:
    """What refining must not change: report.json's posterior summaries and every round's stored ``q``."""
    rep = json.loads((fit_dir / "report.json").read_text())
    store = RunStore.open(fit_dir / "run.zarr")
    qs = [store.read_q(r) for r in store.completed_rounds()]
    return {"report": {k: rep.get(k) for k in POSTERIOR_KEYS},
            "q": [np.concatenate([q.weights.ravel(), q.means.ravel(), q.scale_tril.ravel()]) for q in qs]}


def reevaluate(ctx: SimContext, theta: np.ndarray, metric: str, frames, seeds: list[int]) -> float:
    """Mean of ``metric`` over simulations at ``theta`` with fresh ``seeds`` (the seed changes the surface sampling
    of the Chamfer and the simulator's noise, so a minimum over noisy evaluations is optimistic)."""
    return float(np.mean([score(simulate_job(ctx, (theta, s)), metric, frames) for s in seeds]))


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
    out = {"recording": folder.name, "fit": str(fit_dir), "refine": n, "cma_budget": cma["simulations"],
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recording", help="e.g. lift_tan2 (a folder of --data); with --refine a comma-separated list")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--metric", choices=METRICS, default="fit")
    ap.add_argument("--budget", type=int, default=630, help="simulations (default: a default fit's 4 x 150 + 30)")
    ap.add_argument("--fit", type=Path, help="a finished softsbi fit of the same recording")
    ap.add_argument("--out", type=Path, default=Path("runs/cmaes17"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--table", type=Path, help="print the table of a folder of results and exit")
    ap.add_argument("--overlay", type=Path, help="with --recording: draw this PNG from the stored result and exit")
    ap.add_argument("--refine", type=int, default=0, help="refine each recording's fit (--fits DIR/<r>) with this "
                                                          "many simulations and compare its best fit with CMA-ES's")
    ap.add_argument("--fits", type=Path, default=Path("runs/real56"), help="with --refine: folder of the fits, one "
                                                                            "per recording (lift_tan2 -> DIR/tan2)")
    ap.add_argument("--fit-args", default="", help="with --refine: extra `softsbi fit` arguments of the fit (quoted; "
                                                   "the default fit when empty)")
    ap.add_argument("--workers", type=int, default=1, help="with --refine: simulation workers of the fit")
    ap.add_argument("--reevaluate", type=int, default=3, help="with --refine: fresh seeds re-evaluating both bests")
    a = ap.parse_args()
    if a.refine:
        a.out.mkdir(parents=True, exist_ok=True)
        rows = []
        for name in [r for r in (a.recording or "").split(",") if r]:
            dst = a.out / f"{name}_fit.json"
            cma_res = json.loads(dst.read_text()) if dst.exists() else run(a.data / name, "fit", a.budget, None, a.seed)
            if cma_res["budget"] != a.budget:
                cma_res = run(a.data / name, "fit", a.budget, None, a.seed)
            dst.write_text(json.dumps(cma_res, indent=1))
            row = refine_run(a.data / name, cma_res, a.fits / name.removeprefix("lift_"), a.refine, a.workers,
                             shlex.split(a.fit_args), a.reevaluate)
            (a.out / f"{name}_refine{a.refine}.json").write_text(json.dumps(row, indent=1))
            rows.append(row)
        print(json.dumps({"refine": a.refine, "cma_budget": a.budget, "recordings": rows,
                          "within_5pct": sum(r["within_5pct"] for r in rows), "n": len(rows),
                          "posterior_unchanged": all(r["posterior_unchanged"] for r in rows)}, indent=1))
        return 0
    if a.overlay:
        overlay(a.data / a.recording, a.out / f"{a.recording}_{a.metric}.json", a.overlay)
        return 0
    if a.table:
        table(a.table)
        return 0
    if not a.recording:
        ap.error("give --recording (or --table)")
    a.out.mkdir(parents=True, exist_ok=True)
    dst = a.out / f"{a.recording}_{a.metric}.json"
    if dst.exists():  # resume: add softsbi's side once its fit has finished
        res = json.loads(dst.read_text())
        if "nominal" not in res["evidence"]:
            rec, space, sensor, ctx_s, ctx_f = contexts(a.data / a.recording)
            res["evidence"]["nominal"] = yaw_sweep(ctx_s, space, space.from_unit(np.full(space.dim, 0.5)),
                                                   res["evidence"]["real_axis_deg"])
        if a.fit is not None and (a.fit / "report.json").exists() and not res.get("softsbi"):
            rec, space, sensor, ctx_s, ctx_f = contexts(a.data / a.recording)
            res["softsbi"] = softsbi_side(a.fit, space, ctx_f if a.metric == "full" else ctx_s, a.metric,
                                          sensor["metric_frames"], res["evidence"]["real_axis_deg"], ctx_s)
    else:
        res = run(a.data / a.recording, a.metric, a.budget, a.fit, a.seed)
    dst.write_text(json.dumps(res, indent=1))
    s = res.get("softsbi") or {}
    print(f"{a.recording} {a.metric}: CMA-ES best {res['cma_best_m'] * 100:.2f} cm yaw {res['cma_best'].get('yaw')} "
          f"friction {res['cma_best']['friction']:.2f} scale {res['cma_best']['scale']:.3f}; axis mismatch "
          f"{res['evidence']['cma_axis_mismatch_deg']:+.1f} deg, yaw aligning {res['evidence']['yaw_aligning_axis']}; "
          f"softsbi PM {s.get('posterior_mean_rollout_m')} PP {s.get('posterior_predictive_m')} ({res['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
