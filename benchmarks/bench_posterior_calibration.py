"""The posterior-calibration suite: is every trained model of the lift task calibrated on its held-out simulations?

The demo's task (the built-in lift on mujoco-flex, the demo's recording, the fit's defaults) is trained by
``softsbi task train``'s workflow for the nominal model and every shipped candidate effect the backend applies
(the built-in, non-generic effects: what ``diagnose`` refits), each on ``--prior-sims`` prior simulations, with a
training report on ``--n-test`` held-out prior simulations (``--n-draws`` posterior draws each). The trained models
are stored in the simulation bank under ``--out``, so a run that stops resumes where it stopped: the same command
reads every model already trained.

Each model is trained twice in one run, by two estimators (:data:`ESTIMATORS`): ``previous``, the ``rkhs``
estimator's earlier default written out as options (a shared-trunk ensemble whose joint covariance scale is the
smallest meeting the validation coverage at every level), and ``current``, the ``rkhs`` estimator's default. Both
train on the same prior simulations and are judged on the same held-out ones (the simulation bank serves the
second estimator's simulations). ``--estimators current`` trains one. ``--fresh-test N`` judges every trained
model again on ``N`` fresh held-out prior simulations (:data:`~softsbi.core.seeds.FRESH_TEST_STREAM`): the
estimator was chosen on the training reports' held-out simulations, so these are its test.

Per model, the table reads its training report against three criteria, each at a stated level:

- TARP (Lemos et al. 2023): the KS test of uniformity of its ranks passes at p >= ``TARP_MIN_P`` (0.01);
- HPD coverage at 50% and 90%: inside the binomial band of a calibrated estimator (the report's band at the
  verdict's level, from ``n_test`` held-out cases);
- SBC (Talts et al. 2018) per marginal: the KS p-value of every parameter's rank histogram above ``0.05 / D``
  (Bonferroni over the model's ``D`` parameters).

Usage: ``python -m benchmarks run posterior-calibration --out DIR [--prior-sims 1000] [--n-test 200]
[--candidates a,b] [--estimators previous,current]``; ``--full`` is the reported configuration (every shipped
candidate, 1000 + 200 simulations).
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from benchmarks.runner import in_out_folder, table

#: the TARP criterion: the KS p-value of TARP's ranks at least this
TARP_MIN_P = 0.01
#: the family-wise level of the per-marginal SBC tests (Bonferroni over a model's parameters)
SBC_LEVEL = 0.05
#: the estimators compared, by name: the ``rkhs`` options each trains with (``current``: its default)
ESTIMATORS = {
    "previous": {"ensemble_shared": "trunk", "recal_marginals": False, "recal_rule": "at-least"},
    "current": {},
}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--prior-sims", type=int, default=300, help="prior simulations each model is trained on")
    ap.add_argument("--n-test", type=int, default=200, help="held-out prior simulations of each training report")
    ap.add_argument("--n-draws", type=int, default=1000, help="posterior draws per held-out simulation")
    ap.add_argument("--candidates", default="wind",
                    help="comma-separated candidate effects trained beside the nominal model; 'shipped': every "
                         "built-in candidate the backend applies")
    ap.add_argument("--fresh-test", type=int, default=0,
                    help="also judge every trained model on this many fresh held-out prior simulations (0: none)")
    ap.add_argument("--estimators", default="previous,current",
                    help=f"comma-separated estimators of {sorted(ESTIMATORS)} each model is trained with")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None,
                    help="the simulation bank the models are trained into and read back from (a run resumes there)")


FULL = {"prior_sims": 1000, "n_test": 200, "candidates": "shipped", "fresh_test": 200}


def shipped_candidates(backend: str) -> list[str]:
    """The built-in, non-generic effects ``backend`` applies: the candidates ``diagnose`` refits on a task trained
    with every shipped candidate (installed third-party effects left out)."""
    from softsbi.effects.builtin import softsbi_effects
    from softsbi.plugins import registry
    from softsbi.workflows.criticism.screening import is_generic
    sim = registry().simulator(backend)
    return [e.name for e in softsbi_effects() if not is_generic(e()) and sim.supports(e) is None]


def criteria(report: Any) -> dict[str, Any]:
    """One model's training report against the three criteria (module docstring): each value and whether it
    passes."""
    d = len(report.parameters)
    sbc_p = dict(zip(report.parameters, report.sbc.ks_pvalue))
    sbc_fail = sorted(n for n, p in sbc_p.items() if p < SBC_LEVEL / d)
    cov = report.coverage
    lo50, hi50 = cov.band_50 or (None, None)
    lo90, hi90 = cov.band_90 or (None, None)
    in50 = lo50 is not None and lo50 <= cov.at_50 <= hi50
    in90 = lo90 is not None and lo90 <= cov.at_90 <= hi90
    tarp_p = report.tarp.ks_pvalue
    return {"tarp_p": tarp_p, "tarp_ok": tarp_p is not None and tarp_p >= TARP_MIN_P,
            "at_50": cov.at_50, "band_50": (lo50, hi50), "in_50": in50,
            "at_90": cov.at_90, "band_90": (lo90, hi90), "in_90": in90,
            "sbc_min_p": min(sbc_p.values()), "sbc_threshold": SBC_LEVEL / d, "sbc_fail": sbc_fail,
            "passes": bool(tarp_p is not None and tarp_p >= TARP_MIN_P and in50 and in90 and not sbc_fail),
            "verdict": report.verdict}


def _measure(args: argparse.Namespace, bank: Path) -> dict:
    from softsbi.core.seeds import FRESH_TEST_STREAM
    from softsbi.workflows.demo import demo_recording
    from softsbi.workflows.fit.config import FitConfig
    from softsbi.workflows.tasks.training import held_out_report, held_out_simulations, train_task
    recording, _ = demo_recording(False)
    estimators = [e for e in args.estimators.split(",") if e]
    unknown = sorted(set(estimators) - set(ESTIMATORS))
    if unknown:
        raise SystemExit(f"--estimators: unknown {unknown}; choose from {sorted(ESTIMATORS)}")
    cfg = FitConfig(workers=args.workers, sim_bank=str(bank))
    names = (shipped_candidates(cfg.backend) if args.candidates == "shipped"
             else [n for n in args.candidates.split(",") if n])
    data, fresh, seconds, intervals, switched = [], [], {}, [], []
    for est in estimators:
        t0 = time.perf_counter()
        tasks = train_task(recording, replace(cfg, estimator_options=dict(ESTIMATORS[est])), n_prior=args.prior_sims,
                           candidates=names, n_test=args.n_test, n_draws=args.n_draws, check_null=0, refit_null=0,
                           message=print)
        seconds[est] = time.perf_counter() - t0
        for t in tasks:
            data.append({"estimator": est, "model": t.model, "n_test": t.report.n_test, "n_prior": t.n_prior,
                         "train_seconds": t.report.train_seconds, **criteria(t.report)})
            if args.fresh_test:
                model_cfg = replace(cfg, estimator_options=dict(ESTIMATORS[est]), effects=list(t.identity["effects"]))
                params, u, x = held_out_simulations(recording, model_cfg, args.fresh_test, FRESH_TEST_STREAM)
                report = held_out_report(t.restore(), params, u, x, args.n_draws, cfg.seed)
                fresh.append({"estimator": est, "model": t.model, "n_test": report.n_test,
                              "train_seconds": t.report.train_seconds, **criteria(report)})
        intervals.extend(effect_intervals(est, tasks, recording, cfg, args.n_test, args.n_draws))
        if args.fresh_test:
            switched.extend(switched_on_rates(est, tasks, recording, cfg, args.fresh_test, args.n_draws))
    band = _band(_binomial_band(INTERVAL, args.n_test))
    irows = [[d["model"], d["parameter"], d["estimator"], f"{d['holds']:.3f}", _ok(d["holds_ok"]),
              f"{d['excludes_off']:.3f}", _ok(d["excludes_ok"])] for d in sorted(
        intervals, key=lambda d: (d["model"], d["parameter"], estimators.index(d["estimator"])))]
    tables = [_criteria_table(
        f"Each trained model of the lift task on its training report's {args.n_test} held-out prior simulations "
        f"({args.prior_sims} prior simulations each), by estimator", data)]
    if fresh:
        tables.append(_criteria_table(
            f"The same models on {args.fresh_test} fresh held-out prior simulations (a seed stream of their own, "
            f"judged once: the estimator was chosen on the first table's simulations)", fresh))
    tables.append(table(
        f"The candidates' effect parameters whose off value lies inside the prior: how often the central "
        f"{INTERVAL:.0%} interval holds the truth on the candidate's own held-out simulations, and how often it "
        f"excludes the off value on the nominal model's held-out simulations (the effect absent: a wrong candidate "
        f"'switched on'); calibrated: inside {band} and at most {1 - INTERVAL:.2f} within its band",
        ["candidate", "parameter", "estimator", "holds the truth", f"in {band}", "excludes the off value, effect "
         "absent", "in band"], irows))
    if switched:
        lo, hi = _binomial_band(SWITCHED_ON_LEVEL, args.fresh_test, 0.99)
        tables.append(table(
            f"'Switched on' as the diagnosis decides it for an amortised refit (a Monte-Carlo test of the posterior's "
            f"distance from the off value against the candidate's stored null, at p <= {SWITCHED_ON_LEVEL:g}), on "
            f"{args.fresh_test} fresh held-out prior simulations: of the model without the candidate (the effect "
            f"absent: its rate must lie in the 99% binomial band {lo:.3f}-{hi:.3f} of its nominal "
            f"{SWITCHED_ON_LEVEL:g}) and of the candidate's own model (the effect drawn from its prior: the power, "
            f"averaged over the prior, small values included); beside them the 90% interval rule's rate on the "
            f"same simulations without the effect",
            ["candidate", "estimator", "null size", "switched on, effect absent", "in the 99% band",
             "interval rule, effect absent", "switched on, effect present"],
            [[d["model"], d["estimator"], str(d["null_n"]), f"{d['on_absent']:.3f}", _ok(d["in_band"]),
              "-" if d["interval_absent"] is None else f"{d['interval_absent']:.3f}", f"{d['on_present']:.3f}"]
             for d in switched]))
    notes = []
    for est in estimators:
        mine = [d for d in data if d["estimator"] == est]
        notes.append(f"{est} ({_options(ESTIMATORS[est])}): {_counts(mine)}"
                     + (f"; on the fresh simulations {_counts([d for d in fresh if d['estimator'] == est])}"
                        if fresh else "")
                     + f". Training the {len(mine)} estimators took {sum(d['train_seconds'] or 0 for d in mine):.0f} "
                       f"s; the whole run of this estimator {seconds[est]:.0f} s (models already in the bank are "
                       f"read, not trained; simulations the bank holds are read, not simulated).")
    return {"tables": tables,
            "notes": notes + ["An effect whose off value is a prior bound is named by the posterior pressing that "
                              "bound, not by its interval, so its parameters are not in the interval table; the "
                              "calibrated test's table holds every candidate."],
            "data": {"models": data, "fresh": fresh, "candidates": names, "switched_on": switched,
                     "estimators": {e: ESTIMATORS[e] for e in estimators}, "intervals": intervals}}


def _counts(rows: list[dict]) -> str:
    return (f"{sum(d['passes'] for d in rows)} of {len(rows)} models pass all three criteria (TARP "
            f"{sum(d['tarp_ok'] for d in rows)}, HPD 50% {sum(d['in_50'] for d in rows)}, HPD 90% "
            f"{sum(d['in_90'] for d in rows)}, SBC {sum(not d['sbc_fail'] for d in rows)})")


def _criteria_table(title: str, data: list[dict]) -> dict:
    rows = []
    for model in dict.fromkeys(d["model"] for d in data):
        for d in (d for d in data if d["model"] == model):
            rows.append([model, d["estimator"], _p(d["tarp_p"]), _ok(d["tarp_ok"]),
                         f"{d['at_50']:.3f} ({_band(d['band_50'])})", _ok(d["in_50"]),
                         f"{d['at_90']:.3f} ({_band(d['band_90'])})", _ok(d["in_90"]),
                         f"{d['sbc_min_p']:.2g} vs {d['sbc_threshold']:.2g}", ", ".join(d["sbc_fail"]) or "none",
                         "passes" if d["passes"] else "fails", f"{d['train_seconds']:.0f}"])
    return table(title, ["model", "estimator", "TARP KS p", f">= {TARP_MIN_P}", "HPD coverage 50% (band)", "inside",
                         "HPD coverage 90% (band)", "inside", "SBC min KS p vs Bonferroni", "SBC marginals off",
                         "all three", "training s"], rows)


#: the credibility of the effect parameters' interval (the diagnosis's: an effect is on when its 90% interval
#: excludes its off value)
INTERVAL = 0.9


def _binomial_band(p: float, n: int, level: float = 0.95) -> tuple[float, float]:
    """The central ``level`` band of the fraction of ``n`` Bernoulli(``p``) cases."""
    from scipy import stats
    return (float(stats.binom.ppf((1 - level) / 2, n, p) / n), float(stats.binom.ppf((1 + level) / 2, n, p) / n))


def effect_intervals(estimator: str, tasks: list, recording: Any, cfg: Any, n_test: int, n_draws: int,
                     stream: int | None = None) -> list[dict]:
    """Per candidate model of ``tasks`` (the nominal first) and per parameter of its effect whose off value lies
    strictly inside the prior: the rate at which the posterior's central :data:`INTERVAL` interval holds the truth
    on the model's own held-out simulations, and the rate at which it excludes the off value on the nominal
    model's held-out simulations (same seeds and settings, the effect absent); ``stream``: their seed stream (None:
    the training reports')."""
    from softsbi.core.errors import PosteriorError
    from softsbi.inference import calibration as cal
    from softsbi.plugins import registry
    from softsbi.workflows.tasks.training import held_out_simulations
    import numpy as np
    from softsbi.core.seeds import TEST_STREAM
    stream = TEST_STREAM if stream is None else stream
    _, _, x_nominal = held_out_simulations(recording, cfg, n_test, stream)
    rng = np.random.default_rng(0)
    lo_q, hi_q = (1 - INTERVAL) / 2, (1 + INTERVAL) / 2

    def intervals(est: Any, x: np.ndarray, dim: int) -> np.ndarray:  # (n, D, 2) unit cube
        qs = cal.posteriors_at(est, x)
        out = np.full((len(qs), dim, 2), np.nan)
        for i, q in enumerate(qs):
            try:
                d = cal.draws_in_box(q, n_draws, rng)
            except PosteriorError:  # no mass in the prior box: no interval (left out of both rates)
                continue
            out[i] = np.stack([np.quantile(d, lo_q, axis=0), np.quantile(d, hi_q, axis=0)], -1)
        return out

    band = _binomial_band(INTERVAL, n_test)
    off_band = _binomial_band(1 - INTERVAL, n_test)
    out = []
    for t in tasks[1:]:
        effect = registry().effect(t.identity["effects"][-1])()
        off = effect.nominal()
        names, u_own, x_own = held_out_simulations(recording, replace(cfg, estimator_options=dict(
            t.estimator.options), effects=list(t.identity["effects"])), n_test, stream)
        inside = [p for p in effect.param_space() if p.low < off.get(p.name, p.low) < p.high]
        if not inside:
            continue
        est = t.restore()
        own, absent = intervals(est, x_own, len(names)), intervals(est, x_nominal, len(names))
        for p in inside:
            j = names.index(p.name)
            v = off[p.name]
            u_off = ((np.log(v) - np.log(p.low)) / (np.log(p.high) - np.log(p.low)) if p.log
                     else (v - p.low) / (p.high - p.low))
            ok_own, ok_abs = np.isfinite(own[:, j, 0]), np.isfinite(absent[:, j, 0])
            holds = float(np.mean((own[ok_own, j, 0] <= u_own[ok_own, j]) & (u_own[ok_own, j] <= own[ok_own, j, 1])))
            excl = float(np.mean((absent[ok_abs, j, 0] > u_off) | (absent[ok_abs, j, 1] < u_off)))
            out.append({"estimator": estimator, "model": t.model, "parameter": p.name, "holds": holds,
                        "holds_ok": band[0] <= holds <= band[1], "excludes_off": excl,
                        "excludes_ok": excl <= off_band[1], "no_mass": int((~ok_own).sum() + (~ok_abs).sum())})
    return out


#: the level of the calibrated "switched on" test (the diagnosis's: softsbi.core.results.joint.CHANCE_EXCLUDED)
SWITCHED_ON_LEVEL = 0.1


def switched_on_rates(estimator: str, tasks: list, recording: Any, cfg: Any, n_fresh: int, n_draws: int) -> list[dict]:
    """Per candidate model of ``tasks`` (the nominal first) with a stored "switched on" null: how often the
    diagnosis's calibrated test (:mod:`softsbi.workflows.criticism.switched_on`) calls the effect on, on ``n_fresh``
    fresh held-out prior simulations (:data:`~softsbi.core.seeds.FRESH_TEST_STREAM`) of the model without it and
    of its own model, and how often the 90% interval rule does on the former (off values inside the prior only)."""
    from softsbi.core.seeds import FRESH_TEST_STREAM
    from softsbi.plugins import registry
    from softsbi.workflows.criticism.switched_on import stored_off_null, unit_off_values
    from softsbi.workflows.fit.config import fit_param_space
    from softsbi.workflows.tasks.training import held_out_simulations
    out = []
    for t in tasks[1:]:
        null = stored_off_null(t.path)
        if null is None:
            continue
        effects = list(t.identity["effects"])
        effect = registry().effect(effects[-1])()
        model_cfg = replace(cfg, estimator_options=dict(t.estimator.options), effects=effects)
        _, space = fit_param_space(model_cfg.resolved(recording), recording.scenario)
        off = unit_off_values(effect, space)
        _, _, x_own = held_out_simulations(recording, model_cfg, n_fresh, FRESH_TEST_STREAM)
        _, _, x_absent = held_out_simulations(recording, replace(model_cfg, effects=effects[:-1]), n_fresh,
                                              FRESH_TEST_STREAM)
        est = t.restore()

        on_absent = _on_rate(est, x_absent, off, null, n_draws, 11)
        lo, hi = _binomial_band(SWITCHED_ON_LEVEL, n_fresh, 0.99)
        interval = [d["excludes_off"] for d in effect_intervals(estimator, [tasks[0], t], recording, cfg, n_fresh,
                                                                 n_draws, FRESH_TEST_STREAM)]
        out.append({"estimator": estimator, "model": t.model, "null_n": int(len(null)), "on_absent": on_absent,
                    "in_band": bool(lo <= on_absent <= hi), "on_present": _on_rate(est, x_own, off, null, n_draws, 12),
                    "interval_absent": max(interval) if interval else None})
    return out


def _on_rate(est: Any, x: Any, off: Any, null: Any, n_draws: int, seed: int) -> float:
    """The share of the simulations ``x`` whose posterior the calibrated test calls switched on."""
    import numpy as np
    from softsbi.workflows.criticism.statistics import mc_pvalue
    from softsbi.workflows.criticism.switched_on import train_off_null
    stats = train_off_null(est, x, off, n_draws, seed)
    stats = stats[np.isfinite(stats)]
    return float(np.mean([mc_pvalue(v, null).value <= SWITCHED_ON_LEVEL + 1e-12 for v in stats]))


def _options(opts: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in opts.items()) or "the rkhs default"


def _p(p: float | None) -> str:
    return "-" if p is None else f"{p:.2g}"


def _ok(ok: bool) -> str:
    return "yes" if ok else "no"


def _band(b: tuple[float | None, float | None]) -> str:
    return "-" if b[0] is None else f"{b[0]:.3f}-{b[1]:.3f}"


def suite(args: argparse.Namespace) -> dict:
    return in_out_folder(_measure, args)
