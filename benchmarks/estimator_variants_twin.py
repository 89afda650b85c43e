"""Estimator variants on a well-specified twin: which training choice moves the posterior-mean rollout (issue 17).

Issue 17 asks for softsbi's posterior-mean (PM) rollout within 10% of CMA-ES's best at equal budget; on
well-specified twins of the real lift recordings (``cmaes_twin.py``) CMA-ES reaches the truth's own score (the
floor) and the PM rollout stays 1.11-1.46 times above it. This script asks whether a different training of the
final posterior would close that gap, and how much of it is the training's own randomness:

1. the twin of recording ``R`` (``cmaes_twin.twin``: ``R``'s scenario, sensor model and points per frame, its
   clouds replaced by one simulation at the posterior mean of ``--truth-fit``), fitted once with the defaults
   (``FitConfig(workers=1)``: 4 x 150 truncated + 30 rollouts; skipped when ``OUT/<R>_twin<S>`` is finished);
2. the floor: the truth simulated with 5 seeds the twin did not use, on the headline metric;
3. for every variant (estimator options over the fit's own, :data:`VARIANTS`) and training seed: the final
   round's estimator retrained on all the fit's simulations (the fit's own training set and frames), the
   posterior at the twin's measurement (restricted to the prior box, as the fit does), its mean in physical
   units (as ``report.json``'s ``posterior_mean``) rolled out once (seed 0) on the headline metric, and the
   posterior mean's error in the unit cube, also in posterior standard deviations.

The retraining keeps the fit's simulations: it measures the estimator, not the proposals the variant would have
drawn in earlier rounds. Results: ``OUT/<R>_twin<S>_variants.json`` (rows already there are kept: resumable).

Usage:
    python benchmarks/estimator_variants_twin.py --recording lift_tan --truth-fit /work/bench_runs/trunc/tan \
        --out /work/bench_runs/s34/variants --seeds 0,1,2
    python benchmarks/estimator_variants_twin.py --table /work/bench_runs/s34/variants
    python benchmarks/estimator_variants_twin.py --recording lift_navy --truth-fit /work/bench_runs/trunc/navy \
        --out /work/bench_runs/s34/variants --seeds 0,1,2,3,4,5 --seed-average
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import cmaes_baseline as cb  # noqa: E402
import cmaes_twin as ct  # noqa: E402

from softsbi.core.distributions import PosteriorChain  # noqa: E402
from softsbi.core.store import RunStore  # noqa: E402
from softsbi.plugins import registry  # noqa: E402
from softsbi.workflows.fit import FitConfig, _usable, estimator_options, run_fit  # noqa: E402
from softsbi.workflows.jobs import simulate_job  # noqa: E402

#: estimator options over the fit's own (rkhs defaults: a recalibrated shared-trunk ensemble of 5, 8-point
#: training subsets, 32 frequencies, bandwidth 0.5)
VARIANTS: dict[str, dict] = {
    "default": {},
    "no-recalibration": {"recalibrate": False},
    "every-point": {"point_subset": None},
    "subset-32": {"point_subset": 32},
    "independent-5": {"ensemble_shared": "none", "point_subset": None, "lr": 1e-3, "patience": 15},
    "single-network": {"ensemble": 1, "recalibrate": False},
    "patience-30": {"patience": 30},
    "features-64": {"rkhs_features": 64},
    "bandwidth-0.25": {"rkhs_sigma": 0.25},
    "features-64-bandwidth-0.25": {"rkhs_features": 64, "rkhs_sigma": 0.25},
    "bandwidth-1": {"rkhs_sigma": 1.0},
    "moments": {"frame_moments": True},
    "thickness": {"frame_thickness": True},
}


def training_set(store: RunStore) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Every usable simulation of a finished fit (all rounds, as its last training saw them; the fit's own
    selection, ``softsbi.workflows.fit._usable``): ``(u, x, n, rounds)``."""
    rounds = len(store.completed_rounds())
    u, x, counts = _usable(store, rounds - 1)
    return u, x, sum(counts), rounds


def retrain(store: RunStore, space, options: dict, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The final round's posterior retrained with ``options`` and training seed ``seed``: 4000 draws in the unit cube
    (restricted to the prior box), their mean in physical units and their mean and sd in the unit cube."""
    cfg = FitConfig.from_run_config(store.config)
    u, x, n, rounds = training_set(store)
    fr = slice(None) if cfg.frames is None else list(cfg.frames)
    est_cls = registry().estimator(cfg.estimator)
    est = est_cls(**{**estimator_options(cfg, est_cls), **options})  # the fit's own options, then the variant's
    est.fit(u.astype(np.float64), x[:, fr].astype(np.float64), seed=cfg.seed + rounds - 1 + 1000 * seed)
    q = est.posterior_at(store.read_observed()["x"][fr])
    post = PosteriorChain(space.dim, seed=cfg.seed).add_round(q, n)
    draws = post.sample(4000, np.random.default_rng(cfg.seed))
    return space.from_unit(draws).mean(0), draws.mean(0), draws.std(0)


def run(folder: Path, truth_fit: Path, out: Path, twin_seed: int, variants: list[str], seeds: list[int]) -> dict:
    """Fit the twin (once), its floor, then every variant x seed (rows already in the result file are kept)."""
    theta = json.loads((truth_fit / "report.json").read_text())["posterior_mean"]
    rec, th, space = ct.twin(folder, theta, twin_seed)
    _, _, sensor, ctx_s, _ = cb.contexts_of(rec)
    frames = sensor["metric_frames"]
    fit_dir = out / f"{folder.name}_twin{twin_seed}"
    if not (fit_dir / "report.json").exists():
        run_fit(fit_dir, rec, FitConfig(workers=1), make_plots=False)
    path = out / f"{folder.name}_twin{twin_seed}_variants.json"
    res = json.loads(path.read_text()) if path.exists() else {}
    if "floor_m" not in res:
        floor = ct.floor_runs(ctx_s, th, frames)
        rep = json.loads((fit_dir / "report.json").read_text())
        pm = space.as_array(rep["posterior_mean"])
        res = {"recording": f"{folder.name} twin {twin_seed}", "truth": space.as_dict(th), "fit": str(fit_dir),
               "floor_m": float(np.mean(floor)), "floor_runs_m": floor,
               "fit_pm_rollout_m": cb.score(simulate_job(ctx_s, (pm, 0)), "fit", frames),
               "fit_posterior_predictive_m": rep["chamfer_posterior_m"], "rows": []}
    store = RunStore.open(fit_dir / "run.zarr")
    u_true = space.to_unit(th)
    done = {(r["variant"], r["seed"]) for r in res["rows"]}
    for name in variants:
        for s in seeds:
            if (name, s) in done:
                continue
            t0 = time.perf_counter()
            pm, m, sd = retrain(store, space, VARIANTS[name], s)
            val = cb.score(simulate_job(ctx_s, (pm, 0)), "fit", frames)
            res["rows"].append({"variant": name, "options": VARIANTS[name], "seed": s, "pm_rollout_m": val,
                                "pm_unit_error": (m - u_true).tolist(), "pm_error_sd": ((m - u_true) / sd).tolist(),
                                "posterior_sd_unit": sd.tolist(), "seconds": time.perf_counter() - t0})
            path.write_text(json.dumps(res, indent=1))
            print(f"{name} seed {s}: PM rollout {val * 100:.3f} cm ({val / res['floor_m']:.2f} x floor)", flush=True)
    path.write_text(json.dumps(res, indent=1))
    return res


def seed_average(folder: Path, truth_fit: Path, out: Path, twin_seed: int, seeds: list[int]) -> dict:
    """Does averaging over training seeds move the posterior mean closer? The default retrained with each of
    ``seeds`` (as :func:`run`), each posterior mean rolled out, then the average of the first ``k`` posterior
    means (physical units) rolled out for ``k = 2..len(seeds)``: if the rollout's excess over the floor were
    the training's randomness, it would shrink with ``k``. Results: ``OUT/<R>_twin<S>_seed_average.json``."""
    res = run(folder, truth_fit, out, twin_seed, [], [])  # the twin's fit and floor, nothing retrained
    theta = json.loads((truth_fit / "report.json").read_text())["posterior_mean"]
    rec, th, space = ct.twin(folder, theta, twin_seed)
    _, _, sensor, ctx_s, _ = cb.contexts_of(rec)
    frames = sensor["metric_frames"]
    store = RunStore.open(out / f"{folder.name}_twin{twin_seed}" / "run.zarr")
    pms, single, averaged = [], [], []
    for s in seeds:
        pms.append(retrain(store, space, {}, s)[0])
        single.append(cb.score(simulate_job(ctx_s, (pms[-1], 0)), "fit", frames) / res["floor_m"])
        print(f"seed {s}: PM rollout / floor {single[-1]:.3f}", flush=True)
    for k in range(2, len(pms) + 1):
        averaged.append(cb.score(simulate_job(ctx_s, (np.mean(pms[:k], 0), 0)), "fit", frames) / res["floor_m"])
        print(f"average of the first {k} posterior means: PM rollout / floor {averaged[-1]:.3f}", flush=True)
    summary = {"recording": res["recording"], "seeds": seeds, "single_over_floor": single,
               "average_of_first_k_over_floor": dict(zip(range(2, len(pms) + 1), averaged))}
    (out / f"{folder.name}_twin{twin_seed}_seed_average.json").write_text(json.dumps(summary, indent=1))
    return summary


def table(folder: Path) -> None:
    """Markdown table: per twin and variant, the PM rollout over the floor (mean, range over training seeds)."""
    files = sorted(folder.glob("*_variants.json"))
    res = [json.loads(f.read_text()) for f in files]
    names = [v for v in VARIANTS if any(r["variant"] == v for x in res for r in x["rows"])]
    print("| variant | " + " | ".join(f"{x['recording']}: PM rollout / floor (seeds)" for x in res) + " | mean |")
    print("|---|" + "---|" * (len(res) + 1))
    for v in names:
        cells, means = [], []
        for x in res:
            vals = [r["pm_rollout_m"] / x["floor_m"] for r in x["rows"] if r["variant"] == v]
            if vals:
                means.append(np.mean(vals))
                cells.append(f"{np.mean(vals):.2f} ({min(vals):.2f}-{max(vals):.2f}, n={len(vals)})")
            else:
                cells.append("-")
        print(f"| {v} | " + " | ".join(cells) + f" | {np.mean(means):.2f} |")
    for x in res:
        print(f"\n{x['recording']}: floor {x['floor_m'] * 100:.3f} cm; the fit's own PM rollout "
              f"{x['fit_pm_rollout_m'] * 100:.3f} cm ({x['fit_pm_rollout_m'] / x['floor_m']:.2f} x floor), posterior "
              f"predictive {x['fit_posterior_predictive_m'] * 100:.3f} cm")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ct.add_twin_arguments(ap)
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of {', '.join(VARIANTS)}")
    ap.add_argument("--seeds", default="0,1,2", help="training seeds")
    ap.add_argument("--out", type=Path, default=Path("runs/estimator_variants"))
    ap.add_argument("--table", type=Path, help="print the table of a folder of results and exit")
    ap.add_argument("--seed-average", action="store_true", help="instead of the variants: the default retrained "
                    "with each of --seeds and the average of the posterior means rolled out (seed_average)")
    a = ct.parse_twin_arguments(ap, table)
    if a is None:
        return 0
    unknown = [v for v in a.variants.split(",") if v not in VARIANTS]
    if unknown:
        ap.error(f"unknown variant(s) {', '.join(unknown)}; choose from {', '.join(VARIANTS)}")
    a.out.mkdir(parents=True, exist_ok=True)
    if a.seed_average:
        seed_average(a.data / a.recording, a.truth_fit, a.out, a.twin_seed, [int(s) for s in a.seeds.split(",")])
        return 0
    run(a.data / a.recording, a.truth_fit, a.out, a.twin_seed, a.variants.split(","),
        [int(s) for s in a.seeds.split(",")])
    return 0


if __name__ == "__main__":
    sys.exit(main())
