"""The calibrated-check suite: is the posterior predictive check's p-value uniform on controls, and how fast does its
power grow with a hidden effect's size, before and after calibration against replicate data refitted under the model?

The posterior predictive p-value uses the data twice (to fit and to test) and is not uniform under the model
(Meng 1994; Bayarri & Berger 2000): a recording is closer to its own posterior predictive than a fresh draw is, so
p-values pile up near 1 and small misfits go unseen. Hjort, Dahl & Steinbakk (2006) calibrate it: the same
procedure (fit, then check) is run on replicate recordings simulated under the model from the prior, and the
calibrated p-value of a recording is the fraction of replicates whose statistic is at least its own. Under the
model, with the recording's parameters drawn from the prior, it is exactly uniform (the recording and the replicates
are exchangeable), whatever the statistic. A trained task makes the refit of a replicate one conditioning of its
stored estimator, so a replicate costs one simulation and the check's posterior-predictive rollouts.

Every case here (the calibration's replicates, the controls and the hidden-effect cases) goes through one procedure,
:mod:`softsbi.workflows.criticism.check_null`'s, that of a stored-task fit and its ``check``: simulate a recording (the cloth at
prior-drawn hidden parameters, with the hidden effect for the effect cases), observe it with the fit's observer,
condition the demo task's stored estimator on it, simulate ``check``'s 30 posterior-predictive rollouts (posterior
draws restricted to the prior box, as the fit's evaluation samples are), and compute ``check``'s omnibus statistic
(mean squared standardised deviation of the sensor-faithful summaries,
:func:`~softsbi.workflows.criticism.statistics.misspecification_test`) and its leave-one-out p-value, the first stage of
``check``'s uncalibrated test. The directional test and the null's extension to 200 rollouts are not part of it.
The replicates are those ``softsbi task train --check-null`` stores.

Tables: the p-values of the controls, uncalibrated and calibrated against the ``--null`` replicates (share at 1,
share at or below 0.05 with its Clopper-Pearson interval, Kolmogorov-Smirnov p against the uniform); the share of
hidden-breeze cases rejected at 0.05 per breeze speed, both ways; and the cost.

Usage: ``python -m benchmarks run calibrated-check [--null 100] [--controls 60] [--speeds 0.4,0.8,1.6]
[--per-speed 6] [--out DIR]``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.runner import in_out_folder, table


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--null", type=int, default=100, help="replicate recordings the calibration compares with")
    ap.add_argument("--controls", type=int, default=60, help="control recordings (the nominal model, prior draws)")
    ap.add_argument("--speeds", default="0.4,0.8,1.6", help="hidden breeze speeds wind_y (m/s), comma-separated")
    ap.add_argument("--per-speed", type=int, default=6, help="recordings per breeze speed")
    ap.add_argument("--prior-sims", type=int, default=1000, help="prior simulations the task is trained on")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="keep the bank (the trained task) here")


FULL = {"null": 200, "controls": 100, "per_speed": 10}
LEVEL = 0.05
#: seed streams of the controls and the breeze cases (the replicates' is check_null.NULL_STREAM)
STREAMS = {"control": 8081, "breeze": 8082}


def _shares(p: np.ndarray) -> list:
    from scipy.stats import beta, kstest
    k, n = int(np.sum(p <= LEVEL)), len(p)
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return [n, round(float(np.mean(p >= 0.999)), 3), f"{k / n:.3f} [{lo:.3f}, {hi:.3f}]",
            float(f"{kstest(p, 'uniform').pvalue:.3g}")]


def measure(a: argparse.Namespace, folder: Path) -> dict:
    from scipy.stats import ks_2samp
    from softsbi.workflows.demo import demo_recording
    from softsbi.workflows.fit.run import FitConfig
    from softsbi.workflows.fit.config import fit_param_space
    from softsbi.workflows.tasks.training import train_task
    from softsbi.workflows.criticism.check_null import case_statistics, replicates, stored_check_null
    from softsbi.core.defaults import N_NULL
    from softsbi.workflows.fit.task_store import first_round_context
    cfg = FitConfig(workers=a.workers, sim_bank=str(folder / "bank"))
    rec0 = demo_recording(True)[0]
    t0 = time.perf_counter()
    (task,) = train_task(rec0, cfg, a.prior_sims, candidates=[], check_null=a.null)  # the replicates: task train's
    train_s = time.perf_counter() - t0
    cfg = cfg.resolved(rec0)
    _, space = fit_param_space(cfg, rec0.scenario)
    null = stored_check_null(task, N_NULL, rec0.dense.shape[1])
    est, ctx = task.restore(), first_round_context(cfg, rec0, space)

    def stats(stream: int, n: int, speed: float = 0.0):
        breeze = {"effects": ["wind"], "extra": {"wind_x": 0.0, "wind_y": speed}} if speed else {}
        recs, seeds = replicates(cfg, space, rec0, n, stream, **breeze)
        st = case_statistics(recs, est, cfg, space, ctx, N_NULL, seeds, a.workers)
        return st[np.isfinite(st[:, 0])]  # a recording its fit could not check is no case (check_null)

    def calibrated(d: np.ndarray) -> np.ndarray:
        return np.array([null.p_value(v).value for v in d])

    ctrl = stats(STREAMS["control"], a.controls)
    rows = [["controls, uncalibrated (leave-one-out)", *_shares(ctrl[:, 1])],
            ["controls, calibrated", *_shares(calibrated(ctrl[:, 0]))]]
    exchangeable = ks_2samp(ctrl[:, 0], null.statistics).pvalue
    power, breezes = [], {}
    for speed in [float(s) for s in a.speeds.split(",")]:
        br = stats(STREAMS["breeze"] + int(round(speed * 1000)), a.per_speed, speed)
        breezes[str(speed)] = br.tolist()
        cal = calibrated(br[:, 0])
        power.append([speed, len(br), int(np.sum(br[:, 1] <= LEVEL)), int(np.sum(cal <= LEVEL)),
                      round(float(np.median(br[:, 1])), 3), round(float(np.median(cal)), 3)])
    return {"tables": [
        table(f"p-values on controls (the nominal model at prior draws) at level {LEVEL}",
              ["p-value", "recordings", "share p = 1", f"share p <= {LEVEL} [95% Clopper-Pearson]",
               "KS p (uniform)"], rows),
        table(f"power: recordings with a hidden breeze (wind_y, cloth at prior draws) rejected at {LEVEL}",
              ["wind_y m/s", "recordings", "rejected, uncalibrated", "rejected, calibrated", "median p uncalibrated",
               "median p calibrated"], power)],
        "data": {"replicates": list(null.statistics), "controls": ctrl.tolist(), "breeze": breezes},
        "notes": [f"The controls' statistics against the replicates' (two-sample Kolmogorov-Smirnov, the test of "
                  f"their exchangeability): p = {exchangeable:.3g}. The one-sample KS p of the calibrated p-values "
                  f"is approximate: every control is ranked against the same {len(null.statistics)} replicates, so "
                  f"their p-values are positively dependent (Bates et al. 2023).",
                  f"`softsbi task train --check-null {a.null}`: the calibration's {a.null} replicates cost "
                  f"{a.null * (N_NULL + 1)} simulations, once per task; with the task's training it took "
                  f"{train_s:.0f} s on {a.workers} workers (0 when stored). Each case: one recording, one "
                  f"conditioning of the stored estimator, {N_NULL} posterior-predictive rollouts."]}


def suite(a: argparse.Namespace) -> dict:
    return in_out_folder(measure, a)
