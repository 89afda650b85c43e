"""Which installed effect is missing? A linearised screening, then refits of the top candidates.

:func:`diagnose_run` ranks candidate effects by how much of the residual each explains: with
summaries ``s``, the residual ``r = s_obs - s(theta_hat)`` is regressed on the sensitivities of
the nominal parameters ``J_theta`` and of the effect ``J_E`` (finite differences at the posterior
median, one simulation per direction; the engines are deterministic). The statistic is the drop
of the weighted residual sum of squares when ``J_E`` joins ``J_theta`` (effect parameters kept
inside their prior range); its null distribution comes from posterior-predictive simulations of
the nominal model treated as if they were the measurement (a Gamma fit of that null gives the
p-value). Candidates are ranked, and selected forward, by that p-value, since raw residual drops
are not comparable across effects with different parameters. Top candidates are then confirmed
by a short refit with the effect switched on (:func:`confirm_candidates`).
"""
from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy import stats
from scipy.optimize import lsq_linear

from softsbi.core.errors import SoftsbiError
from softsbi.core.types import STATUS_OK
from softsbi.plugins import registry
from softsbi.workflows.check import FEATURE_FLOOR, sampled_points, trajectory_features
from softsbi.core.types import Recording
from softsbi.workflows.fit import FitConfig, run_fit
from softsbi.workflows.jobs import run_jobs
from softsbi.workflows.runs import RunView, load_run


def _candidate_effects(run: RunView, names: Sequence[str] | None) -> list[Any]:
    reg = registry()
    sim_cls = reg.simulator(run.config["backend"])
    if names:
        cands = [reg.effect(n) for n in names]
        bad = [f"{c.name} (it needs {sim_cls.supports(c)})" for c in cands if sim_cls.supports(c) is not None]
        if bad:
            raise SoftsbiError(f"backend '{sim_cls.name}' cannot apply {bad}; it supports {list(sim_cls.effects)}")
    else:
        cands = [reg.effect(n) for n in sim_cls.effects if n in reg.tables["effect"] and not reg.effect(n).generic]
    return [c() for c in cands if c.name not in run.effects]


def diagnose_run(run_dir: str | Path, effects: Sequence[str] | None = None, n_null: int = 30,
                 unit_step: float = 0.05, effect_step: float = 0.25, alpha: float = 0.01,
                 workers: int | None = None, confirm: int = 2, confirm_budget: dict[str, int] | None = None,
                 seed: int = 0, progress: Any = None) -> dict[str, Any]:
    """Rank installed effects by how much of the residual each explains; writes ``diagnosis.json``.

    Args:
        run_dir: a finished fit of the nominal model.
        effects: candidate effect names (default: every installed effect the backend supports
            and the run does not already include).
        n_null: posterior-predictive simulations forming the null distribution.
        unit_step: finite-difference step of the nominal parameters (unit-cube units).
        effect_step: finite-difference step of each effect parameter (fraction of its range).
        alpha: family-wise significance level (Bonferroni over candidates).
        confirm: refit the top ``confirm`` candidates (:func:`candidates_to_confirm`) with the
            effect switched on (0 = no refit), report the change in posterior-predictive Chamfer
            and select the effect whose refit lowers it most (:func:`confirm_candidates`).
        confirm_budget: ``{"rounds": r, "sims_per_round": n}`` of the confirmation refits
            (default: the run's own).
        progress: optional ``callable(str)`` told which effect is being refitted.

    Returns:
        dict with ``ranking`` (effect, explained_fraction, statistic, p_value, log10_p, estimate,
        ...; ordered by evidence, i.e. by the p-value against each effect's own null),
        ``significant`` (names, forward selection), ``confirmed`` (refit results, best first),
        ``selected`` (the effect to add: the best confirmed one, else the first significant one,
        else None), ``final_ranking`` (effect names: refitted ones by error drop, then the
        screening's order) and ``summary`` (plain language).
    """
    t0 = time.perf_counter()
    run = load_run(run_dir, n_null, seed)
    cands = _candidate_effects(run, effects)
    if not cands:
        raise SoftsbiError("no candidate effects: install effect plugins or name them with --effect")
    jobs, eff_cols, n_fd = _sensitivity_jobs(run, cands, unit_step, effect_step)
    res = run_jobs(run.sim_context(keep_rollout=True), jobs, workers)
    screen = _Screening(run, cands, res, eff_cols, n_fd, effect_step)
    ranking = screen.ranking()
    thr = alpha / max(len(screen.design), 1)
    significant, steps_log = screen.forward_selection(ranking, thr)
    out = {"run": str(run.path), "candidates": [c.name for c in cands], "ranking": ranking,
           "significance_threshold": thr, "significant": significant, "selection": steps_log,
           "confirmed": [], "selected": significant[0] if significant else None,
           "final_ranking": [r["effect"] for r in ranking],
           "summary": "", "simulations": len(jobs), "seconds": time.perf_counter() - t0}
    out["summary"] = _diagnosis_sentence(run, out)
    if confirm:
        confirm_candidates(run, out, confirm, confirm_budget, workers, progress=progress)
    (Path(run_dir) / "diagnosis.json").write_text(json.dumps(out, indent=2))
    return out


def _sensitivity_jobs(run: RunView, cands: list[Any], unit_step: float,
                      effect_step: float) -> tuple[list[tuple[dict, int, tuple]], list[tuple[Any, str, int, int]], int]:
    """The simulations of the screening, as job items ``(theta, seed, effects)``: the posterior
    median; one finite-difference step per nominal parameter; per candidate the effect at its
    nominal value and one step per effect parameter; then the posterior-predictive rollouts that
    form the null. Returns the items, the effect columns ``(effect, parameter, index with the
    step, index at nominal)`` and the number of finite-difference items."""
    base = run.median()
    space = run.space
    u_hat = np.clip(space.to_unit(space.as_array({k: base[k] for k in space.names})), 0, 1)
    jobs: list[tuple[dict, int, tuple]] = [(dict(base), 0, tuple(run.effects))]
    for j in range(space.dim):
        s = unit_step if u_hat[j] + unit_step <= 1 else -unit_step
        u = u_hat.copy()
        u[j] += s
        v = dict(base)
        v.update(space.as_dict(space.from_unit(u)))
        jobs.append((v, 0, tuple(run.effects)))
    eff_cols: list[tuple[Any, str, int, int]] = []
    for eff in cands:
        es = eff.param_space()
        nom = eff.nominal()
        v0 = dict(base)
        v0.update(nom)
        jobs.append((v0, 0, tuple(run.effects) + (eff.name,)))
        i_nom = len(jobs) - 1
        for p in es:
            u0 = es.subset([p.name]).to_unit(np.array([nom[p.name]]))[0]
            s = effect_step if u0 + effect_step <= 1 else -effect_step
            v = dict(v0)
            v[p.name] = float(es.subset([p.name]).from_unit(np.array([u0 + s]))[0])
            jobs.append((v, 0, tuple(run.effects) + (eff.name,)))
            eff_cols.append((eff, p.name, len(jobs) - 1, i_nom))
    n_fd = len(jobs)
    for i, th in enumerate(run.post_theta):
        jobs.append((run.values(th), 2000 + i, tuple(run.effects)))
    return jobs, eff_cols, n_fd


class _Screening:
    """The linearised added-variable test of every candidate, from the screening's simulations.

    Residuals are standardised summary statistics: ``r_obs`` of the measurement and ``r_null`` of
    the posterior-predictive rollouts, both relative to the posterior median's; ``J_theta`` holds
    the nominal parameters' sensitivities, ``design[name]`` each effect's offset, sensitivities
    and the coefficient bounds that keep its parameters inside their prior range.
    """

    def __init__(self, run: RunView, cands: list[Any], res: list[dict[str, Any]],
                 eff_cols: list[tuple[Any, str, int, int]], n_fd: int, effect_step: float):
        n_pts = run.dense.shape[1]
        # finite-difference simulations share one sampling seed (common random numbers); the null
        # simulations each get their own, like the measurement
        feats = [trajectory_features(sampled_points(r["vertices"], r["faces"], n_pts, 0 if i < n_fd else 5000 + i))
                 if r["status"] == STATUS_OK else None for i, r in enumerate(res)]
        if feats[0] is None:
            raise SoftsbiError(f"the simulation at the posterior median failed: {res[0]['reason']}")
        f0 = feats[0]
        null_f = np.array([f for f in feats[n_fd:] if f is not None])
        if len(null_f) < 5:
            raise SoftsbiError("too few successful posterior-predictive simulations for the null distribution")
        sd = np.maximum(null_f.std(0), FEATURE_FLOOR)
        self.J_theta = np.stack([(feats[1 + j] - f0) / sd if feats[1 + j] is not None else np.zeros_like(f0)
                                 for j in range(run.space.dim)], 1)
        self.r_obs = (trajectory_features(run.dense) - f0) / sd
        self.r_null = (null_f - f0) / sd
        self.design: dict[str, dict[str, Any]] = {}
        self.failed: list[dict[str, Any]] = []
        for eff in cands:
            self._add_design(eff, [c for c in eff_cols if c[0] is eff], feats, f0, sd, effect_step)

    def _add_design(self, eff: Any, cols: list[tuple[Any, str, int, int]], feats: list[Any], f0: np.ndarray,
                    sd: np.ndarray, effect_step: float) -> None:
        # offset: the effect switched on at its nominal value (e.g. wind at 0 m/s still adds air)
        if any(feats[c[2]] is None or feats[c[3]] is None for c in cols) or feats[cols[0][3]] is None:
            self.failed.append({"effect": eff.name, "error": "a sensitivity simulation failed"})
            return
        es = eff.param_space()
        lo, hi, steps = [], [], []
        for c in cols:
            ps1 = es.subset([c[1]])
            u0 = ps1.to_unit(np.array([eff.nominal()[c[1]]]))[0]
            step = effect_step if u0 + effect_step <= 1 else -effect_step
            lo.append(min(-u0 / step, (1 - u0) / step))
            hi.append(max(-u0 / step, (1 - u0) / step))
            steps.append((c[1], u0, step))
        self.design[eff.name] = {"effect": eff, "J": np.stack([(feats[c[2]] - feats[c[3]]) / sd for c in cols], 1),
                                 "offset": (feats[cols[0][3]] - f0) / sd, "lo": np.array(lo), "hi": np.array(hi),
                                 "steps": steps}

    def sse(self, r: np.ndarray, names: Sequence[str]) -> tuple[float, np.ndarray]:
        """Weighted residual sum of squares of the best linearised fit with effects ``names``, and
        the effects' coefficients."""
        big = 1e3
        design, J_theta = self.design, self.J_theta
        rr = r - sum((design[n]["offset"] for n in names), np.zeros_like(r))
        A = np.concatenate([J_theta] + [design[n]["J"] for n in names], 1)
        lb = np.concatenate([np.full(J_theta.shape[1], -big)] + [design[n]["lo"] for n in names])
        ub = np.concatenate([np.full(J_theta.shape[1], big)] + [design[n]["hi"] for n in names])
        fit = lsq_linear(A, rr, bounds=(lb, ub))
        return float(((rr - A @ fit.x) ** 2).sum()), fit.x[J_theta.shape[1]:]

    def test(self, name: str, given: list[str]) -> dict[str, Any]:
        """Does effect ``name`` explain residual beyond the effects ``given``? The drop in the
        residual sum of squares against its null over the posterior-predictive rollouts."""
        base_obs, _ = self.sse(self.r_obs, given)
        with_obs, coef = self.sse(self.r_obs, given + [name])
        d_obs = base_obs - with_obs
        null = np.array([self.sse(r, given)[0] - self.sse(r, given + [name])[0] for r in self.r_null])
        p_emp = (1 + (null >= d_obs).sum()) / (len(null) + 1)
        pos = null[null > 1e-12]
        if d_obs <= 0:
            log_p = 0.0
        elif len(pos) >= 3:
            ga, _, gscale = stats.gamma.fit(pos, floc=0)
            log_p = _gamma_logsf(d_obs, ga, gscale) + np.log(len(pos) / len(null))
        else:
            log_p = float(np.log(p_emp))
        log_p = min(0.0, log_p)
        est = {}
        dsg = self.design[name]
        k = len(coef) - len(dsg["steps"])
        for (pname, u0, step), cval in zip(dsg["steps"], coef[k:]):
            ps1 = dsg["effect"].param_space().subset([pname])
            est[pname] = float(ps1.from_unit(np.array([np.clip(u0 + cval * step, 0, 1)]))[0])
        return {"statistic": float(d_obs), "explained_fraction": float(d_obs / max(base_obs, 1e-12)),
                "null_mean": float(null.mean()), "p_value": float(p_emp), "p_value_gamma": float(np.exp(log_p)),
                "log10_p": log_p / np.log(10), "estimate": est}

    @staticmethod
    def evidence(t: dict[str, Any]) -> tuple[float, float]:
        """Sort key: p-value first (each statistic is calibrated by its own null: effects differ in
        their number of parameters and nonlinearity, so raw residual drops are not comparable)."""
        return (t["log10_p"], -t["explained_fraction"])

    def ranking(self) -> list[dict[str, Any]]:
        """Every candidate tested alone, by evidence; failed candidates last."""
        ranking = [{"effect": name, "description": dsg["effect"].description, **self.test(name, [])}
                   for name, dsg in self.design.items()]
        ranking.sort(key=self.evidence)
        return ranking + self.failed

    def forward_selection(self, ranking: list[dict[str, Any]], thr: float) -> tuple[list[str], list[dict[str, Any]]]:
        """Effects selected forward: one is significant if it explains residual beyond those already
        chosen (p below ``thr`` and more than 10% of the residual). Returns them and the steps."""
        significant: list[str] = []
        remaining = [r["effect"] for r in ranking if "statistic" in r]
        steps_log = []
        while remaining:
            tests = {n: (self.test(n, significant) if significant else next(r for r in ranking if r["effect"] == n))
                     for n in remaining}
            best = min(tests, key=lambda n: self.evidence(tests[n]))
            t = tests[best]
            steps_log.append({"given": list(significant), "best": best, "p_value_gamma": t["p_value_gamma"],
                              "explained_fraction": t["explained_fraction"]})
            if t["p_value_gamma"] < thr and t["explained_fraction"] > 0.1:
                significant.append(best)
                remaining.remove(best)
            else:
                break
        return significant, steps_log


def format_p(test: dict[str, Any]) -> str:
    """A candidate's p-value for people: ``2.1e-19``, or ``1e-1234`` from ``log10_p`` where the
    float underflows to 0."""
    p = test.get("p_value_gamma", float("nan"))
    if p > 0 or not np.isfinite(test.get("log10_p", np.nan)):
        return f"{p:.2g}"
    return f"1e{int(np.floor(test['log10_p']))}"


def _gamma_logsf(x: float, a: float, scale: float) -> float:
    """``log P(X > x)`` for ``X ~ Gamma(a, scale)``, finite far in the tail.

    SciPy's ``logsf`` underflows to ``-inf`` when ``x / scale`` is in the thousands, which would
    tie every strongly significant effect; there the leading term of the asymptotic expansion of
    the upper incomplete gamma function is used (Abramowitz & Stegun 6.5.32):
    ``log Q(a, z) ~ (a - 1) log z - z - log Gamma(a) + log(1 + (a - 1) / z)``.
    """
    lsf = float(stats.gamma.logsf(x, a, scale=scale))
    return lsf if np.isfinite(lsf) else _gamma_logsf_asymptotic(x / scale, a)


def _gamma_logsf_asymptotic(z: float, a: float) -> float:
    """``log Q(a, z)`` for ``z >> a`` (A&S 6.5.32, two terms)."""
    from scipy.special import gammaln
    return float((a - 1) * np.log(z) - z - gammaln(a) + np.log1p((a - 1) / z))


def candidates_to_confirm(out: dict[str, Any], confirm: int) -> list[str]:
    """The top candidates a diagnosis refits: the forward selection's first effect, then the
    other effects that are significant on their own (``p < threshold`` and > 10 % of the
    residual), in ranking order, ``confirm`` at most.

    Near-collinear effects (air drag and extra damping in a fling are both velocity-dependent
    drags) can each explain most of the residual in the linearised screening; only a refit tells
    which one the data prefer.
    """
    names = list(out["significant"][:1])
    for r in out["ranking"]:
        if len(names) >= confirm:
            break
        if "statistic" in r and r["effect"] not in names and r["p_value_gamma"] < out["significance_threshold"] \
                and r["explained_fraction"] > 0.1:
            names.append(r["effect"])
    return names[:confirm]


def confirm_candidates(run: "RunView | str | Path", out: dict[str, Any], confirm: int,
                       budget: dict[str, int] | None = None, workers: int | None = None,
                       progress: Any = None) -> dict[str, Any]:
    """Refit the top ``confirm`` candidates of a diagnosis ``out`` (from :func:`diagnose_run`)
    and select the effect whose refit lowers the posterior-predictive Chamfer most.

    Updates ``out`` in place: ``confirmed`` (one refit result per candidate, ordered by error
    drop), ``selected`` (the effect with the largest drop, or the screening's first choice when
    no refit lowers the error) and ``summary``.

    Args:
        progress: optional ``callable(str)`` told which effect is being refitted.
    """
    view = run if isinstance(run, RunView) else load_run(run)
    for name in candidates_to_confirm(out, confirm):
        if any(c["effect"] == name for c in out["confirmed"]):
            continue
        if progress:
            progress(name)
        out["confirmed"].append(confirm_effect(view, name, budget, workers))
    out["confirmed"].sort(key=lambda c: -(c["drop"] if c.get("drop") is not None else -np.inf))
    best = out["confirmed"][0] if out["confirmed"] else None
    if best is not None and (best.get("drop") or 0) > 0:
        out["selected"] = best["effect"]
    # the diagnosis's final order: refitted candidates by their error drop, then the screening's
    done = [c["effect"] for c in out["confirmed"]]
    out["final_ranking"] = done + [r["effect"] for r in out["ranking"] if r["effect"] not in done]
    out["summary"] = _diagnosis_sentence(view, out)
    return out


def _diagnosis_sentence(run: RunView, out: dict[str, Any]) -> str:
    ranking, significant, thr = out["ranking"], out["significant"], out["significance_threshold"]
    confirmed = out.get("confirmed") or []
    if not significant:
        top = ranking[0] if ranking else None
        extra = (f" (best candidate {top['effect']} explains {top['explained_fraction'] * 100:.0f}% of the "
                 f"residual, p = {format_p(top)} > {thr:.2g})") if top and "statistic" in top else ""
        return "No missing effect detected: no candidate explains the residual beyond what the nominal model's " \
               "own posterior spread produces" + extra + "."
    chosen = out.get("selected") or significant[0]
    top = next(r for r in ranking if r["effect"] == chosen)
    est = ", ".join(f"{k} ~ {v:.3g}" for k, v in top["estimate"].items())
    s = (f"The nominal model misses the measurement; {top['effect']} ({top['description']}) explains "
         f"{top['explained_fraction'] * 100:.0f}% of the residual (p = {format_p(top)}; linearised "
         f"estimate {est}).")
    done = [c for c in confirmed if c.get("chamfer_after_m")]
    for c in done:
        if c["effect"] == chosen:
            s += (f" Refitting with it lowers the posterior-predictive Chamfer from {c['chamfer_before_m'] * 100:.2f} "
                  f"to {c['chamfer_after_m'] * 100:.2f} cm ({c['drop'] * 100:.0f}% lower)")
            others = [o for o in done if o["effect"] != chosen]
            s += ("; " + ", ".join(f"with {o['effect']} instead: {o['chamfer_after_m'] * 100:.2f} cm "
                                   f"({o['drop'] * 100:.0f}% lower)" for o in others) + ", so the data favour "
                  f"{chosen}." if others else ".")
    rest = [n for n in significant if n != chosen]
    if chosen != significant[0]:
        s += (f" (The linearised screening ranked {significant[0]} first; the refits decide between these "
              f"near-collinear candidates.)")
    elif rest:
        s += f" Also needed beyond it: {', '.join(rest)}."
    else:
        s += " No other candidate explains significantly more once it is included."
    return s


def recording_from_run(run: RunView):
    """Rebuild the :class:`~softsbi.workflows.fit.Recording` a run was fitted to."""
    return Recording(scenario=run.scenario, x=run.x_obs, dense=run.dense,
                       source=run.config.get("observed_source", ""), truth=run.config.get("truth"))


def confirm_effect(run: RunView, effect: str, budget: dict[str, int] | None = None,
                   workers: int | None = None) -> dict[str, Any]:
    """Refit ``run``'s measurement with ``effect`` added (into ``RUN/refit-<effect>``), with the
    run's own settings (:meth:`FitConfig.from_run_config`: executor and its options included), the
    effect switched on and, where given, ``budget`` ``{"rounds", "sims_per_round"}`` and ``workers``.

    Returns:
        ``{"effect", "run", "chamfer_before_m", "chamfer_after_m", "drop", "posterior_mean"}``.
    """
    budget = budget or {}
    base = FitConfig.from_run_config(run.config)
    cfg = replace(base, effects=list(run.effects) + [effect],
                  rounds=int(budget.get("rounds", base.rounds)),
                  sims_per_round=int(budget.get("sims_per_round", base.sims_per_round)),
                  workers=workers if workers is not None else base.workers)
    out = run.path / f"refit-{effect}"
    res = run_fit(out, recording_from_run(run), cfg)
    before = run.report.get("chamfer_posterior_m")
    after = res.report.get("chamfer_posterior_m")
    return {"effect": effect, "run": str(out), "chamfer_before_m": before, "chamfer_after_m": after,
            "drop": (1 - after / before) if before and after else None,
            "posterior_mean": res.report["posterior_mean"]}


