"""Study: CMA-ES against softsbi on well-specified twins of the real lift recordings.

Conclusion. softsbi's posterior-mean (PM) rollout of a default fit (4 x 150 truncated + 30) was 1.05-1.22 times
CMA-ES's best at the same 630 simulations on the five second-repeat lift recordings (within 10 % on one). On their
twins, where the nominal model is exactly true, it was 1.11-1.46 times (within 10 % on none), while CMA-ES reached the
truth's own score (0.99 of it) on every twin and every truth lay inside every 90 % interval: the gap is not the
misspecification. A calibrated posterior's centre at 630 simulations is not an optimiser's argmin; sixteen levers on
the estimator's training, the summaries and the budget's split into rounds (measured on the tuning twins and
recordings) did not close it, and the training seed alone moves the ratio by about +-0.1. With twice the simulations
(4 x 300) the PM rollout came within 10 % of CMA-ES's 630-simulation best on three of five recordings. A point
estimate at equal budget is what ``softsbi fit --refine N`` adds (CMA-ES started at the posterior's best fit).

The twin of recording ``R``: ``R``'s scenario (its gripper path and calibration), its sensor model (height cut,
``frames: auto``) and its points per frame, with its clouds replaced by one simulation (surface samples of the cloth
mesh, full clouds: the height cut is applied by the fit and the metric, to both clouds, as on the real recording) at
``theta*`` = the posterior mean of a finished softsbi fit of ``R`` (a realistic cloth; ``--truth-fit``), seed
``--twin-seed``. On it:

* a default ``softsbi fit`` (``FitConfig(workers=1)``: 4 x 150 truncated, 30 posterior rollouts);
* CMA-ES (``cma``) with the same 630 simulations on the headline metric (:func:`benchmarks.cmaes_baseline.run`);
* both on the same metric: the posterior-mean rollout, the posterior predictive, CMA-ES's best, and
  the truth's own score (``floor``: ``theta*`` simulated with a seed the twin did not use).

Usage (``--truth-fit``: a default fit of the recording, e.g. from the real-lift suite's ``--out DIR``):
    python -m benchmarks.studies.cmaes_twin --recording lift_tan2 --truth-fit DIR/tan2 --out runs/cmaes_twin
    python -m benchmarks.studies.cmaes_twin --table runs/cmaes_twin
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.fit.jobs import JobItem, simulate_job

from benchmarks import cmaes_baseline as cb


def twin(folder: Path, theta: dict[str, float], seed: int):
    """The twin of the recording in ``folder``: its :class:`~softsbi.core.types.Recording` with ``dense``
    replaced by one simulation at ``theta`` (physical units, the fit's parameters), seed ``seed``, as many
    points per frame as the recording's; ``x`` is rebuilt from it by the fit. Returns ``(recording,
    theta array, parameter space)``."""
    rec, space, _, _, ctx_full = cb.contexts(folder)
    th = space.as_array(theta)
    res, clouds = cb.simulated_clouds(ctx_full, th, seed, rec.dense.shape[1])
    if clouds is None:
        raise RuntimeError(f"the twin's simulation failed: {res.reason}")
    return dataclasses.replace(rec, dense=np.stack(clouds), x=None, truth=space.as_dict(th),
                               source=f"twin of {folder.name} (seed {seed})"), th, space


def floor_runs(ctx_s, theta: np.ndarray, frames: list[int] | None, n: int = 5) -> list[float]:
    """The truth's own score (m, headline metric): ``theta`` simulated in the sensor context ``ctx_s`` with ``n``
    seeds (9000, 9001, ...) that neither the twin nor the fits use."""
    return [cb.score(simulate_job(ctx_s, JobItem(theta, 9000 + k)), "fit", frames) for k in range(n)]


def parse_twin_arguments(ap: argparse.ArgumentParser, table) -> argparse.Namespace | None:
    """Parse a twin script's command line: with ``--table FOLDER`` print ``table(FOLDER)`` and return None;
    otherwise refuse, in one line, a run that does not name the twin (``--recording`` and ``--truth-fit``)."""
    a = ap.parse_args()
    if a.table:
        table(a.table)
        return None
    if not (a.recording and a.truth_fit):
        ap.error("--recording and --truth-fit name the twin (or print a table with --table FOLDER)")
    return a


def add_twin_arguments(ap: argparse.ArgumentParser) -> None:
    """The options that name a twin (``--recording``, ``--data``, ``--truth-fit``, ``--twin-seed``)."""
    ap.add_argument("--recording", help="e.g. lift_tan2 (a folder of --data)")
    ap.add_argument("--data", type=Path, default=cb.DATA)
    ap.add_argument("--truth-fit", type=Path, help="a finished softsbi fit of the recording: its posterior mean "
                                                   "is the twin's truth")
    ap.add_argument("--twin-seed", type=int, default=1)


def run_twin(folder: Path, truth_fit: Path, out: Path, twin_seed: int, budget: int, seed: int) -> dict:
    """Fit the twin with softsbi, run CMA-ES on it at ``budget`` simulations, and score both and the truth."""
    t0 = time.perf_counter()
    theta = json.loads((truth_fit / "report.json").read_text())["posterior_mean"]
    rec, th, space = twin(folder, theta, twin_seed)
    fit_dir = out / f"{folder.name}_twin{twin_seed}"
    run_fit(fit_dir, rec, FitConfig(workers=1), make_plots=False)
    fit_s = time.perf_counter() - t0
    res = cb.run(folder, "fit", budget, fit_dir, seed, rec=rec)
    _, _, sensor, ctx_s, _ = cb.contexts_of(rec)
    floor = floor_runs(ctx_s, th, sensor["metric_frames"])
    res.update(recording=f"{folder.name} twin {twin_seed}", truth=space.as_dict(th), truth_fit=str(truth_fit),
               floor_m=float(np.mean(floor)), floor_runs_m=floor, fit_seconds=fit_s,
               seconds=time.perf_counter() - t0)
    res.pop("history_m", None)
    return res


def table(folder: Path) -> None:
    """Markdown table of every twin result in ``folder``."""
    print("| twin | truth's own score (floor) [cm] | CMA-ES best [cm] | softsbi posterior-mean rollout [cm] | "
          "softsbi posterior predictive [cm] | prior [cm] | post. pred. / prior | PM rollout / CMA-ES best | "
          "CMA-ES best / floor | yaw truth / CMA-ES / posterior mean [deg] |")
    print("|" + "---|" * 10)
    for f in sorted(folder.glob("*.json")):
        r = json.loads(f.read_text())
        s = r["softsbi"]
        print(f"| {r['recording']} | {r['floor_m'] * 100:.2f} | {r['cma_best_m'] * 100:.2f} | "
              f"{s['posterior_mean_rollout_m'] * 100:.2f} | {s['posterior_predictive_m'] * 100:.2f} | "
              f"{s['prior_m'] * 100:.2f} | {s['posterior_predictive_m'] / s['prior_m']:.2f} | "
              f"{s['posterior_mean_rollout_m'] / r['cma_best_m']:.2f} | {r['cma_best_m'] / r['floor_m']:.2f} | "
              f"{r['truth'].get('yaw', float('nan')):+.1f} / {r['cma_best'].get('yaw', float('nan')):+.1f} / "
              f"{s['posterior_mean'].get('yaw', float('nan')):+.1f} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_twin_arguments(ap)
    ap.add_argument("--budget", type=int, default=630)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/cmaes_twin"))
    ap.add_argument("--table", type=Path, help="print the table of a folder of results and exit")
    a = parse_twin_arguments(ap, table)
    if a is None:
        return 0
    a.out.mkdir(parents=True, exist_ok=True)
    res = run_twin(a.data / a.recording, a.truth_fit, a.out, a.twin_seed, a.budget, a.seed)
    (a.out / f"{a.recording}_twin{a.twin_seed}.json").write_text(json.dumps(res, indent=1))
    s = res["softsbi"]
    print(f"{res['recording']}: floor {res['floor_m'] * 100:.2f} cm, CMA-ES best {res['cma_best_m'] * 100:.2f} cm, "
          f"PM rollout {s['posterior_mean_rollout_m'] * 100:.2f} cm "
          f"({s['posterior_mean_rollout_m'] / res['cma_best_m']:.2f}x), post. pred. {s['posterior_predictive_m'] * 100:.2f} cm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
