"""The calibrated-check suite: is the check of a trained task's fit at its nominal size on controls, and how fast does
its power grow with a hidden effect's size?

The posterior predictive p-value uses the data twice (to fit and to test) and is not uniform under the model
(Meng 1994; Bayarri & Berger 2000): a recording is closer to its own posterior predictive than a fresh draw is, so
p-values pile up near 1 and small misfits go unseen. Hjort, Dahl & Steinbakk (2006) calibrate it: the same
procedure (fit, then check) is run on replicate recordings simulated under the model from the prior, and the
calibrated p-value of a recording is its rank among them. Under the model, with the recording's parameters drawn
from the prior, it is exactly uniform (the recording and the replicates are exchangeable), whatever the statistic.

Every case here (the calibration's replicates, the controls and the hidden-effect cases) goes through one procedure,
:mod:`softsbi.workflows.criticism.check_null`'s, that of a stored-task fit and its ``check``: simulate a recording (the
cloth at prior-drawn hidden parameters, with the hidden effect for the effect cases), observe it, condition the demo
lift task's stored estimator on it, simulate ``check``'s 30 posterior-predictive rollouts, compute the omnibus
statistic with its leave-one-out p-value, and screen the candidate family about the posterior median (each
candidate's directional statistic). Three p-values per case:

- **check (calibrated, both tests)**: what ``check`` and ``diagnose``'s detection give: the omnibus and the largest
  directional statistic combined by min-P against the task's ``--null`` screened replicates
  (:meth:`~softsbi.workflows.criticism.check_null.CheckNull.joint_p_value`);
- **refit check (omnibus, 19 replicates)**: what a candidate refit's adequacy check gives on a task trained with
  ``task train``'s defaults (``--refit-null 19``, not screened): the omnibus statistic's rank among the first 19
  replicates; on the nominal model's cases it measures that check's size and power at its resolution;
- **uncalibrated omnibus**: the leave-one-out posterior predictive p-value.

Tables: the p-values of the controls (share at 1, share at or below 0.05 with its Clopper-Pearson interval,
Kolmogorov-Smirnov p against the uniform); the share of hidden-effect cases rejected at 0.05 per effect and
magnitude, each way; and the cost. Each stage's statistics are kept in ``--out`` and read again by a rerun.

Usage: ``python -m benchmarks run calibrated-check [--null 40] [--controls 60] [--fresh-controls] [--per-magnitude 5]
[--out DIR]``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.runner import in_out_folder, table


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--null", type=int, default=40, help="screened replicate recordings of the nominal model")
    ap.add_argument("--controls", type=int, default=60, help="control recordings (the nominal model, prior draws)")
    ap.add_argument("--fresh-controls", action="store_true",
                    help="also a second set of --controls controls from a seed stream of its own "
                         "(STREAMS['fresh control']), tabled beside the first: fresh cases to judge a rule chosen on "
                         "the first ones")
    ap.add_argument("--per-magnitude", type=int, default=5, help="recordings per hidden effect and magnitude")
    ap.add_argument("--prior-sims", type=int, default=1000, help="prior simulations the task is trained on")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="keep the bank (the trained task) and the stages here")


FULL = {"controls": 100, "per_magnitude": 10}
LEVEL = 0.05
#: a candidate refit's replicates (``task train --refit-null``'s default)
REFIT_NULL = 19
#: the hidden effects of the power table: one parameter each, at an eighth, a quarter, half and all of its prior's
#: largest distance from its off value (the other parameters of the effect at their off values)
MAGNITUDES = {"wind": ("wind_y", (0.25, 0.5, 1.0, 2.0)),
              "heavy-hem": ("hem_density", (0.00625, 0.0125, 0.025, 0.05)),
              "time-offset": ("time_offset", (0.0125, 0.025, 0.05, 0.1))}
#: seed streams of the controls and of the effect cases (the replicates' is check_null.NULL_STREAM)
STREAMS = {"control": 8081, "effect": 8200, "fresh control": 8082}


def _shares(p: np.ndarray) -> list:
    from scipy.stats import beta, kstest
    k, n = int(np.sum(p <= LEVEL)), len(p)
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return [n, round(float(np.mean(p >= 0.999)), 3), f"{k / n:.3f} [{lo:.3f}, {hi:.3f}]",
            float(f"{kstest(p, 'uniform').pvalue:.3g}")]


def measure(a: argparse.Namespace, folder: Path) -> dict:
    from scipy.stats import ks_2samp
    from softsbi.core.defaults import N_NULL
    from softsbi.workflows.criticism.check_null import case_statistics, replicates, stored_check_null
    from softsbi.workflows.criticism.screening import default_candidates
    from softsbi.workflows.criticism.statistics import mc_pvalue
    from softsbi.workflows.demo import demo_recording
    from softsbi.workflows.fit.config import fit_param_space
    from softsbi.workflows.fit.run import FitConfig
    from softsbi.workflows.fit.task_store import first_round_context
    from softsbi.workflows.tasks.training import train_task
    cfg = FitConfig(workers=a.workers, sim_bank=str(folder / "bank"))
    rec0 = demo_recording(True)[0]
    t0 = time.perf_counter()
    (task,) = train_task(rec0, cfg, a.prior_sims, candidates=[], check_null=a.null, message=print)
    train_s = time.perf_counter() - t0
    cfg = cfg.resolved(rec0)
    _, space = fit_param_space(cfg, rec0.scenario)
    null = stored_check_null(task, N_NULL, rec0.dense.shape[1])
    family = [c for c in default_candidates(cfg.backend, rec0.scenario, cfg.effects) if c.name in (null.family or ())]
    names = [c.name for c in family]
    est, ctx = task.restore(), first_round_context(cfg, rec0, space)
    stages = folder / "calibrated-check"
    stages.mkdir(parents=True, exist_ok=True)

    def stats(name: str, stream: int, n: int, effect: str | None = None, value: float = 0.0) -> np.ndarray:
        path = stages / f"{name}.json"
        if path.is_file():
            return np.array(json.loads(path.read_text()), float).reshape(-1, 2 + len(family))
        hidden = {} if effect is None else {
            "effects": [effect], "extra": {**registry_nominal(effect), MAGNITUDES[effect][0]: value}}
        recs, seeds = replicates(cfg, space, rec0, n, stream, **hidden)
        st = case_statistics(recs, est, cfg, space, ctx, N_NULL, seeds, a.workers, family)
        st = st[np.isfinite(st[:, 0])]  # a recording its fit could not check is no case (check_null)
        path.write_text(json.dumps(np.where(np.isfinite(st), st, None).tolist()))
        return np.array(st, float)

    def pvalues(st: np.ndarray) -> dict[str, np.ndarray]:
        with np.errstate(all="ignore"):
            z = np.nanmax(st[:, 2:], axis=1)
        refit = np.asarray(null.statistics[:REFIT_NULL])
        return {"check": np.array([null.joint_p_value(np.array([o, d]), names).value for o, d in zip(st[:, 0], z)]),
                "refit": np.array([mc_pvalue(o, refit).value for o in st[:, 0]]), "uncalibrated": st[:, 1]}

    t1 = time.perf_counter()
    sets = {"controls": stats("controls", STREAMS["control"], a.controls)}
    if a.fresh_controls:
        sets["fresh controls"] = stats("controls-fresh", STREAMS["fresh control"], a.controls)
        sets["all controls"] = np.concatenate(list(sets.values()))
    rows, shared = [], []
    for label, st in sets.items():
        pc = pvalues(st)
        rows += [[label, f"check: both tests, calibrated ({len(null.statistics)} replicates)", *_shares(pc["check"])],
                 [label, f"a refit's check: omnibus, calibrated ({REFIT_NULL} replicates)", *_shares(pc["refit"])],
                 [label, "omnibus, uncalibrated (leave-one-out)", *_shares(pc["uncalibrated"])]]
        shared.append(f"{label}: " + shared_set_band(len(null.statistics), len(pc["check"]),
                                                      int(np.sum(pc["check"] <= LEVEL))))
    ctrl = np.concatenate([v for k, v in sets.items() if k != "all controls"])
    exchangeable = ks_2samp(ctrl[:, 0], null.statistics).pvalue
    power, cases = [], {}
    for k, (effect, (param, values)) in enumerate(MAGNITUDES.items()):
        for j, v in enumerate(values):
            st = stats(f"{effect}-{v:g}", STREAMS["effect"] + 10 * k + j, a.per_magnitude, effect, v)
            cases[f"{effect} {param}={v:g}"] = st.tolist()
            p = pvalues(st)
            power.append([effect, f"{param} = {v:g}", len(st), *(int(np.sum(p[w] <= LEVEL))
                                                                 for w in ("check", "refit", "uncalibrated")),
                          round(float(np.median(p["check"])), 3)])
    cases_s = time.perf_counter() - t1
    n_cases = len(ctrl) + sum(len(c) for c in cases.values())
    return {"tables": [
        table(f"p-values on controls (the nominal model at prior draws; each set a seed stream of its own) at level "
              f"{LEVEL}", ["controls", "p-value", "recordings", "share p = 1",
                           f"share p <= {LEVEL} [95% Clopper-Pearson]", "KS p (uniform)"], rows),
        table(f"power: recordings with a hidden effect (cloth at prior draws) rejected at {LEVEL}",
              ["effect", "magnitude", "recordings", "rejected by check", "by a refit's check (omnibus, 19)",
               "uncalibrated", "median p of check"], power)],
        "data": {"replicates": list(null.statistics), "directional": [list(r) for r in null.directional or ()],
                 "family": names, "controls": ctrl.tolist(), "cases": cases},
        "notes": [f"The controls' omnibus statistics against the replicates' (two-sample Kolmogorov-Smirnov, the test "
                  f"of their exchangeability): p = {exchangeable:.3g}. The one-sample KS p of the calibrated p-values "
                  f"is approximate: every control is ranked against the same replicates, so their p-values are "
                  f"positively dependent (Bates et al. 2023).", *shared,
                  f"`softsbi task train --check-null {a.null}`: {a.null} replicates, each refitted, checked on "
                  f"{N_NULL} rollouts and screened against {len(family)} candidates, once per task; with the task's "
                  f"training {train_s:.0f} s on {a.workers} workers (0 when stored). The {n_cases} cases took "
                  f"{cases_s:.0f} s ({cases_s / max(n_cases, 1):.1f} s each: one recording, one conditioning of the "
                  f"stored estimator, {N_NULL} rollouts and the screening; 0 when read from --out)."]}


def shared_set_band(r: int, n: int, k: int) -> str:
    """The false alarms of ``n`` controls ranked against one set of ``r`` replicates, in words: a calibrated check
    rejects at p <= LEVEL when a control's statistic ranks among the top ``j = floor(LEVEL (r + 1))`` of the ``r + 1``
    (p = j / (r + 1)); given the replicate set its size is the share of the model's cases above the set's j-th largest
    statistic, Beta(j, r + 1 - j) distributed, so the count is beta-binomial, not binomial; its 95% band and the
    chance of at least ``k`` false alarms."""
    from scipy.stats import betabinom, binom
    j = int(np.floor(LEVEL * (r + 1) + 1e-9))
    bb = betabinom(n, j, r + 1 - j)
    return (f"Every control is ranked against the same {r} replicates: a calibrated check rejects at p <= {LEVEL} "
            f"when it ranks among the top {j} of {r + 1} (p = {j}/{r + 1}), and given the replicate set its size is "
            f"Beta({j}, {r + 1 - j}) distributed (mean {j / (r + 1):.3f}, sd "
            f"{np.sqrt(j * (r + 1 - j) / ((r + 1) ** 2 * (r + 2))):.3f}), so the false alarms of {n} controls are "
            f"beta-binomial: 95% band {int(bb.ppf(0.025))}-{int(bb.ppf(0.975))}, against the binomial band "
            f"{int(binom(n, LEVEL).ppf(0.025))}-{int(binom(n, LEVEL).ppf(0.975))} of independent sets; "
            f"P(at least {k} of {n}) = {bb.sf(k - 1):.3f} (binomial: {binom(n, LEVEL).sf(k - 1):.3f}).")


def registry_nominal(effect: str) -> dict[str, float]:
    """The effect's off values (its other parameters stay off in an effect case)."""
    from softsbi.plugins import registry
    return dict(registry().effect(effect)().nominal())


def suite(a: argparse.Namespace) -> dict:
    return in_out_folder(measure, a)
