"""The linearised screening of candidate effects and the misspecification test ``check`` and ``diagnose`` share.

- :class:`Screening`: every candidate effect's sensitivity of the summary statistics (finite differences at the
  posterior median, one simulation per direction) and the added-variable statistic: the drop of the weighted
  residual sum of squares when the effect's sensitivities join the nominal parameters' (a linearised test; Cook
  & Weisberg 1982, ch. 2.3), with its null from the posterior-predictive rollouts and the Westfall-Young max-T
  adjustment over the family (:func:`~softsbi.workflows.criticism.statistics.max_t_adjusted`).
- :func:`misspecification_verdict`: "is the measurement inside the posterior predictive distribution?". Two tests
  on one null, combined by the null's own distribution of their smaller p-value
  (:func:`~softsbi.workflows.criticism.statistics.min_p_combined`, :class:`~softsbi.core.results.JointTest`): the omnibus test
  (:func:`~softsbi.workflows.criticism.statistics.misspecification_test`, a departure in any direction) and the directional test
  (the screening's largest max-T statistic: a departure along a candidate's sensitivity). The omnibus test alone
  spreads its power over every direction of the summaries x frames; the directional test concentrates it on the
  directions the installed effects can move the cloth in.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy.optimize import lsq_linear

from softsbi.core.errors import ParameterError, ShapeError, SoftsbiError
from softsbi.core.results import Candidate, JointTest
from softsbi.core.types import ParamSpace
from softsbi.plugins import registry
from softsbi.scenarios.spec import declared_size
from softsbi.core.defaults import ALPHA_BOUND
from softsbi.workflows.fit.jobs import JobItem, JobResult, run_jobs
from softsbi.workflows.fit.runs import RunView
from softsbi.workflows.criticism.stats import (ALPHA, MAX_NULL, PosteriorPredictive, features_of, run_features,
                                               run_summarising)
from softsbi.workflows.criticism.statistics import (
    MIN_NULL,
    mc_pvalue,
    max_t_adjusted,
    max_t_statistics,
    min_p_combined,
    omnibus_statistics,
    resolution_needed,
    summary_floor,
)


#: finite-difference step of a nominal parameter (unit-cube units): small enough that the summaries respond linearly
#: about the posterior median (whose spread in the unit cube is usually 0.1-0.3), large enough that the step moves
#: them well above the float noise of a deterministic engine
UNIT_STEP = 0.05
#: finite-difference step of an effect parameter (fraction of its range) from its switched-off value: an effect is
#: screened where it is off, so the step must switch it on enough to move the cloth measurably (a quarter of its
#: prior); the screening ranks candidates and spends the refit budget, the refits decide
EFFECT_STEP = 0.25
#: bound on the nominal parameters' coefficients in the linearised fit (in finite-difference steps of
#: :data:`UNIT_STEP`): the added-variable test profiles them out, so they are free in effect; 1e3 steps are 50 prior
#: widths, which no fit about a posterior median inside the prior reaches where the linearisation holds, while a
#: parameter the summaries barely respond to (a near-zero column) cannot take an unbounded coefficient
NOMINAL_COEF_BOUND = 1e3


def candidate_effects(run: RunView, names: Sequence[str] | None = None,
                      say: Callable[[str], None] | None = None) -> list[Any]:
    """Instances of the candidate effects of a run: ``names`` (each must be applicable by the run's
    backend to the run's object; an empty list is no candidate), or by default (None) every installed effect the
    backend supports that can act on the run's object (:attr:`~softsbi.core.interfaces.Effect.objects`: e.g. no
    anisotropic membrane on a rope), generic force terms included; effects the run already has are left out.
    Default candidates left out for the object are told to ``say`` in one line.

    Raises:
        SoftsbiError: a named effect the backend cannot apply (naming the door it needs), or that cannot act on
            the run's object.
    """
    reg = registry()
    sim_cls = reg.simulator(run.config.backend)
    kind = object_kind(getattr(run, "scenario", None))
    if isinstance(names, str):
        raise SoftsbiError(f"candidate effects must be a list of names, e.g. [{names!r}]")
    if names is not None:
        cands = [reg.effect(n) for n in names]
        bad = [f"{c.name} (it needs {sim_cls.supports(c)})" for c in cands if sim_cls.supports(c) is not None]
        if bad:
            raise SoftsbiError(f"backend '{sim_cls.name}' cannot apply {bad}; it supports {list(sim_cls.effects)}")
        if off := [c.name for c in cands if not acts_on(c, kind)]:
            raise SoftsbiError(f"{', '.join(off)} cannot act on a {kind} (it acts on "
                               f"{' or '.join(reg.effect(off[0]).objects)}); leave it out of the candidates")
    else:
        return default_candidates(run.config.backend, getattr(run, "scenario", None), run.effects, say)
    return [c() for c in cands if c.name not in run.effects]


def default_candidates(backend: str, scenario: Any, effects: Sequence[str],
                       say: Callable[[str], None] | None = None) -> list[Any]:
    """:func:`candidate_effects`' default family of a fit on ``backend`` of ``scenario`` with ``effects`` on: every
    installed effect the backend supports that can act on the scenario's object, generic force terms included,
    less ``effects`` (those left out for the object told to ``say`` in one line)."""
    reg = registry()
    kind = object_kind(scenario)
    # generic force terms are screened too (in the max-T family), but only for the third verdict: the diagnosis
    # refits and names non-generic effects only
    cands = [reg.effect(n) for n in reg.simulator(backend).effects if n in reg.tables["effect"] and n not in effects]
    off = [c.name for c in cands if not acts_on(c, kind)]
    if off and say is not None:
        say(f"left out of the candidates: {', '.join(off)} (cannot act on a {kind}); the other "
            f"{len(cands) - len(off)} are screened")
    return [c() for c in cands if acts_on(c, kind)]


def acts_on(effect: Any, kind: str) -> bool:
    """Whether an effect (class or instance) can act on an object of ``kind``
    (:attr:`~softsbi.core.interfaces.Effect.objects`; None: on every kind)."""
    objects = getattr(effect, "objects", None)
    return objects is None or kind in objects


def object_kind(scenario: Any) -> str:
    """The kind of a scenario's object (``object.kind``: ``"cloth"`` or ``"rope"``; ``"cloth"`` when it does not
    say, as the backends read it; :func:`~softsbi.scenarios.spec.declared_size` reads it)."""
    return str(declared_size(scenario)[0] or "cloth")


def effect_kind(effect: Any) -> str:
    """``"physics"`` or ``"sensor"``: an effect class's ``kind`` attribute (default physics)."""
    return str(getattr(type(effect), "kind", getattr(effect, "kind", "physics")) or "physics")


def is_generic(effect: Any) -> bool:
    """True for a generic force term (class attribute ``generic = True``: constant force, linear
    or quadratic drag, a position-dependent force field), which describes a residual rather than
    naming a physical cause."""
    return bool(getattr(type(effect), "generic", False))


def inward_step(u: float, step: float) -> float:
    """The finite-difference step from ``u`` (unit cube) that stays inside it: ``+step``, or ``-step`` where ``u +
    step`` would leave it (the screening's and the design's one rule)."""
    return step if u + step <= 1 else -step


def sensitivity_jobs(base: Mapping[str, float], space: ParamSpace, effects: Sequence[str], cands: list[Any],
                     unit_step: float, effect_step: float) -> tuple[list[JobItem], list[tuple[Any, str, int, int]], int]:
    """The finite-difference simulations of the screening about ``base`` (the posterior median, physical units, the
    fixed parameters included) of a fit of the parameters ``space`` with ``effects`` on, as job items (``theta``,
    seed 0, ``effects``): the median; one step per nominal parameter; per candidate the effect at its nominal value
    and one step per effect parameter. Returns the items, the effect columns ``(effect, parameter, index with the
    step, index at nominal)`` and the number of items."""
    u_hat = np.clip(space.to_unit(space.as_array({k: base[k] for k in space.names})), 0, 1)
    effects = tuple(effects)
    jobs: list[JobItem] = [JobItem(dict(base), 0, effects=effects)]
    for j in range(space.dim):
        s = inward_step(u_hat[j], unit_step)
        u = u_hat.copy()
        u[j] += s
        v = dict(base)
        v.update(space.as_dict(space.from_unit(u)))
        jobs.append(JobItem(v, 0, effects=effects))
    eff_cols: list[tuple[Any, str, int, int]] = []
    for eff in cands:
        es = eff.param_space()
        nom = eff.nominal()
        v0 = dict(base)
        v0.update(nom)
        jobs.append(JobItem(v0, 0, effects=effects + (eff.name,)))
        i_nom = len(jobs) - 1
        for p in es:
            u0 = es.subset([p.name]).to_unit(np.array([nom[p.name]]))[0]
            s = inward_step(u0, effect_step)
            v = dict(v0)
            v[p.name] = float(es.subset([p.name]).from_unit(np.array([u0 + s]))[0])
            jobs.append(JobItem(v, 0, effects=effects + (eff.name,)))
            eff_cols.append((eff, p.name, len(jobs) - 1, i_nom))
    return jobs, eff_cols, len(jobs)




def failed_candidate(eff: Any, error: str) -> Candidate:
    """The ranking's row of a candidate the screening could not test, with ``error`` saying why."""
    return Candidate(effect=eff.name, kind=effect_kind(eff), generic=is_generic(eff), description=eff.description,
                     error=error)


class Screening:
    """The linearised added-variable test of every candidate.

    Residuals are standardised summary statistics: ``r_obs`` of the measurement and ``r_null`` of
    the posterior-predictive rollouts (the null: the nominal model's own data), both relative to the
    posterior median's; ``J_theta`` holds the nominal parameters' sensitivities, ``design[name]``
    each effect's offset, sensitivities and the coefficient bounds that keep its parameters inside
    their prior range. A candidate's statistic is the drop of the residual sum of squares when it
    joins the fit; one null rollout gives every candidate's statistic, so the family is tested
    with the max-T null (:func:`max_t_adjusted`).
    """

    def __init__(self, f_obs: np.ndarray, dim: int, cands: list[Any], res: list[JobResult],
                 feats: list[np.ndarray | None], eff_cols: list[tuple[Any, str, int, int]], effect_step: float,
                 null_features: np.ndarray):
        # f_obs: the measurement's summaries; dim: the nominal parameters; res and feats: the finite-difference
        # simulations (:func:`sensitivity_jobs`) and their summaries (None: failed), which share one sampling seed
        # (common random numbers)
        if feats[0] is None:
            raise SoftsbiError(f"the simulation at the posterior median failed: {res[0].reason}")
        f0 = feats[0]
        null_f = np.asarray(null_features)
        if len(null_f) < MIN_NULL:
            raise SoftsbiError(f"too few successful posterior-predictive simulations for the null distribution "
                               f"({len(null_f)}, at least {MIN_NULL} needed)")
        sd = np.maximum(null_f.std(0), summary_floor(null_f.shape[1]))
        self.J_theta = np.stack([(feats[1 + j] - f0) / sd if feats[1 + j] is not None else np.zeros_like(f0)
                                 for j in range(dim)], 1)
        self.r_obs = (np.asarray(f_obs) - f0) / sd
        self.r_null = (null_f - f0) / sd
        self.design: dict[str, dict[str, Any]] = {}
        self.failed: list[Candidate] = []
        for eff in cands:
            self._add_design(eff, [c for c in eff_cols if c[0] is eff], feats, f0, sd, effect_step, res)
        self.n_simulations = len(res)
        #: each null rollout's directional statistic (the max-T maximum over the candidates,
        #: :func:`max_t_statistics`), and each screened candidate's normalised statistic on the measurement, set by
        #: :meth:`ranking`
        self.z_max: np.ndarray | None = None
        self.z_obs: dict[str, float] = {}

    def _add_design(self, eff: Any, cols: list[tuple[Any, str, int, int]], feats: list[Any], f0: np.ndarray,
                    sd: np.ndarray, effect_step: float, res: list[JobResult | None]) -> None:
        # offset: the effect switched on at its nominal value (e.g. wind at 0 m/s still adds air)
        if not cols or any(feats[c[2]] is None or feats[c[3]] is None for c in cols):
            why = next((res[i].reason if res[i] is not None else None for c in cols for i in (c[3], c[2])
                        if feats[i] is None), None)
            self.failed.append(failed_candidate(eff, "a sensitivity simulation failed" + (f": {why}" if why else "")))
            return
        es = eff.param_space()
        lo, hi, steps = [], [], []
        for c in cols:
            ps1 = es.subset([c[1]])
            u0 = ps1.to_unit(np.array([eff.nominal()[c[1]]]))[0]
            step = inward_step(u0, effect_step)
            lo.append(min(-u0 / step, (1 - u0) / step))
            hi.append(max(-u0 / step, (1 - u0) / step))
            steps.append((c[1], u0, step))
        self.design[eff.name] = {"effect": eff, "J": np.stack([(feats[c[2]] - feats[c[3]]) / sd for c in cols], 1),
                                 "offset": (feats[cols[0][3]] - f0) / sd, "lo": np.array(lo), "hi": np.array(hi),
                                 "steps": steps}

    @property
    def z_obs_max(self) -> float | None:
        """The directional test's statistic on the measurement: the largest of :attr:`z_obs` (None before
        :meth:`ranking`, or when no candidate was screened)."""
        return max(self.z_obs.values(), default=None)

    def sse(self, r: np.ndarray, names: Sequence[str]) -> tuple[float, np.ndarray]:
        """Weighted residual sum of squares of the best linearised fit with effects ``names``, and
        the effects' coefficients."""
        big = NOMINAL_COEF_BOUND
        design, J_theta = self.design, self.J_theta
        rr = r - sum((design[n]["offset"] for n in names), np.zeros_like(r))
        A = np.concatenate([J_theta] + [design[n]["J"] for n in names], 1)
        lb = np.concatenate([np.full(J_theta.shape[1], -big)] + [design[n]["lo"] for n in names])
        ub = np.concatenate([np.full(J_theta.shape[1], big)] + [design[n]["hi"] for n in names])
        fit = lsq_linear(A, rr, bounds=(lb, ub))
        return float(((rr - A @ fit.x) ** 2).sum()), fit.x[J_theta.shape[1]:]

    def statistic(self, name: str) -> tuple[float, float, np.ndarray, dict[str, float]]:
        """Residual drop of effect ``name`` on the measurement, the fraction of the residual it explains, the same
        drop on every null rollout ``(n,)`` and the linearised estimate of its parameters (physical units)."""
        base_obs, _ = self.sse(self.r_obs, [])
        with_obs, coef = self.sse(self.r_obs, [name])
        null = np.array([self.sse(r, [])[0] - self.sse(r, [name])[0] for r in self.r_null])
        dsg = self.design[name]
        est = {}
        for (pname, u0, step), cval in zip(dsg["steps"], coef):
            ps1 = dsg["effect"].param_space().subset([pname])
            est[pname] = float(ps1.from_unit(np.array([np.clip(u0 + cval * step, 0, 1)]))[0])
        d_obs = base_obs - with_obs
        return float(d_obs), float(d_obs / max(base_obs, 1e-12)), null, est

    def ranking(self) -> tuple[Candidate, ...]:
        """Every candidate tested alone, with max-T adjusted p-values over the family, by evidence (adjusted p;
        among candidates beyond all nulls, where the normalised statistic saturates at ``sqrt(n)``, by the
        fraction explained; else by the normalised statistic); failed candidates last."""
        names = list(self.design)
        if not names:
            return tuple(self.failed)
        tests = [self.statistic(n) for n in names]
        obs, null = np.array([t[0] for t in tests]), np.stack([t[2] for t in tests], 1)
        adj, z = max_t_adjusted(obs, null)
        z_obs, self.z_max = max_t_statistics(obs, null)
        self.z_obs = dict(zip(names, (float(z) for z in z_obs)))
        rows = []
        for name, (_, frac, _, est), p, zz in zip(names, tests, adj, z):
            eff = self.design[name]["effect"]
            rows.append((p.value, 0.0 if p.at_floor else -float(zz), -frac,
                         Candidate(effect=name, kind=effect_kind(eff), generic=is_generic(eff),
                                   description=eff.description, explained=frac, adjusted=p, estimate=est)))
        rows.sort(key=lambda t: t[:3])
        return tuple(r[3] for r in rows) + tuple(self.failed)


def screening_size(dim: int, cands: Sequence[Any]) -> int:
    """The finite-difference simulations of one screening (:func:`sensitivity_jobs`) of a fit of ``dim`` parameters
    against ``cands``: the median, one per parameter, and per candidate one at its off value and one per parameter
    of it (0 without candidates)."""
    return 1 + dim + sum(1 + len(c.param_space()) for c in cands) if cands else 0


def screening_statistics(ctx: Any, space: ParamSpace, cfg: Any, medians: Sequence[Mapping[str, float] | None],
                         f_obs: Sequence[np.ndarray | None], null_features: Sequence[np.ndarray | None],
                         cands: list[Any], workers: int | None, label: str = "finite differences of the screenings",
                         unit_step: float = UNIT_STEP, effect_step: float = EFFECT_STEP) -> np.ndarray:
    """``(n, C)``: the directional statistics (each candidate's normalised max-T statistic, :attr:`Screening.z_obs`)
    of several recordings of one task without a run each: recording ``i``'s measurement summaries ``f_obs[i]``, its
    posterior median ``medians[i]`` (physical units, the fixed parameters included) and its posterior-predictive null
    ``null_features[i]`` (``(S, F)``), its finite differences simulated in one executor call on ``ctx`` (a
    summarising job context, :func:`~softsbi.workflows.criticism.stats.summarising`). What ``check`` computes of a
    fit, for the replicates that calibrate it. NaN for a recording given as None, whose screening failed, and for a
    candidate it could not screen.
    """
    out = np.full((len(medians), len(cands)), np.nan)
    if not cands:
        return out
    jobs, cols, spans = [], [], []
    for med in medians:
        items, eff_cols = ([], None) if med is None else sensitivity_jobs(med, space, cfg.effects, cands, unit_step,
                                                                          effect_step)[:2]
        cols.append(eff_cols)
        spans.append((len(jobs), len(jobs) + len(items)))
        jobs += [replace(j, summary_seed=0) for j in items]
    res = run_jobs(ctx, jobs, workers, cfg.executor, cfg.executor_options, label=label,
                   contained=(ParameterError, ShapeError)) if jobs else []
    names = [c.name for c in cands]
    for i, ((a, b), eff_cols, f, null) in enumerate(zip(spans, cols, f_obs, null_features)):
        if eff_cols is None or f is None or null is None:
            continue
        part = res[a:b]
        try:
            screen = Screening(f, space.dim, cands, part, [r.features if r is not None and r.ok else None
                                                           for r in part], eff_cols, effect_step, null)
            screen.ranking()
        except SoftsbiError:  # the median's simulation failed: no directional statistic, as check's would be
            continue
        for name, z in screen.z_obs.items():
            out[i, names.index(name)] = z
    return out


# ----------------------------------------------------------------------------------------
# the misspecification test of check and diagnose


def screening_of(pool: PosteriorPredictive, cands: Sequence[Any], unit_step: float = UNIT_STEP,
                 effect_step: float = EFFECT_STEP, null_features: np.ndarray | None = None) -> Screening:
    """The :class:`Screening` of ``cands`` against ``pool``'s current null rollouts (``null_features``: those of some
    of them, e.g. the fit's evaluation samples a calibrated check is computed on).

    The finite-difference simulations (:func:`sensitivity_jobs`: ``1 + dim`` nominal directions plus, per
    candidate, its nominal value and one step per effect parameter) run once per pool and are kept in
    :attr:`~softsbi.workflows.criticism.stats.PosteriorPredictive.sensitivities`, so ``check`` and ``diagnose`` sharing a
    pool simulate them once, and a null grown to its cap re-uses them. The engines are deterministic and every
    job uses seed 0, so a fresh pool gives identical simulations.

    Raises:
        SoftsbiError: the simulation at the posterior median failed; fewer than 5 null rollouts.
    """
    key = (tuple(c.name for c in cands), float(unit_step), float(effect_step))
    run = pool.run
    if key not in pool.sensitivities:
        jobs, eff_cols, _ = sensitivity_jobs(run.median(), run.space, run.effects, list(cands), unit_step, effect_step)
        # an effect the model cannot take (ParameterError: e.g. a membrane edit of a rope) or whose code returns the
        # wrong shape (ShapeError) fails its own jobs only: its refusal never reaches another candidate's row
        res = run_jobs(run_summarising(run, keep_rollout=False), [replace(j, summary_seed=0) for j in jobs],
                       pool.workers, label="finite differences of the screening",
                       contained=(ParameterError, ShapeError))
        pool.sensitivities[key] = (list(cands), eff_cols, res)
    # the stored effect instances: the design's columns refer to them
    first, eff_cols, res = pool.sensitivities[key]
    feats = [features_of(run, r, 0) if r is not None and r.ok else None for r in res]
    return Screening(run_features(run, run.dense), run.space.dim, first, res, feats, eff_cols, effect_step,
                     pool.features if null_features is None else null_features)



def smallest_null(alpha: float) -> int:
    """The smallest null size whose joint p-value can reach ``alpha``: the tests are combined by their null's own
    min-p distribution (:func:`~softsbi.workflows.criticism.statistics.min_p_combined`), whose floor is
    ``1 / (n + 1)`` whatever their number, so ``n = ceil(1 / alpha) - 1`` (19 at 0.05)."""
    return int(np.ceil(1 / alpha - 1e-9)) - 1


def check_resolution(alpha: float, max_null: int) -> None:
    """Refuse a null cap that cannot resolve ``alpha`` (before any simulation).

    Raises:
        SoftsbiError: ``alpha`` outside ``(0, 1)``, or ``max_null < smallest_null(alpha)``: with that cap no
            measurement could ever be found misspecified.
    """
    if (why := ALPHA_BOUND.problem(alpha)) is not None:
        raise SoftsbiError(f"{ALPHA_BOUND.flag} {why}")
    need = smallest_null(alpha)
    if max_null < need:
        raise SoftsbiError(f"max_null {max_null} cannot resolve alpha {alpha:g}: the smallest p-value from "
                           f"{max_null} null simulations is 1/{max_null + 1} = {1 / (max_null + 1):.3g}; use "
                           f"max_null >= {need}")


def misspecification_verdict(pool: PosteriorPredictive, cands: Sequence[Any], alpha: float = ALPHA,
                             max_null: int = MAX_NULL, unit_step: float = UNIT_STEP, effect_step: float = EFFECT_STEP,
                             null: Any = None) -> tuple[JointTest, Screening | None, tuple[Candidate, ...]]:
    """Is the run's measurement inside the posterior predictive distribution? ``check``'s test, ``diagnose``'s
    detection step and the adequacy of every refit (one function, one null: the commands never disagree).

    The omnibus test (:func:`~softsbi.workflows.criticism.statistics.misspecification_test`) and the directional test (the
    screening's strongest candidate, max-T adjusted over ``cands``) on the pool's rollouts, combined by the null's own
    distribution of the smaller of their p-values (:func:`~softsbi.workflows.criticism.statistics.min_p_combined`):
    each null rollout's two statistics against the others' play the measurement's. Adaptive resolution
    (:func:`~softsbi.workflows.criticism.statistics.resolution_needed` on the joint p-value at ``alpha``): when the
    first stage is promising (or rejects), the null grows once to ``max_null`` successful rollouts and both tests are
    decided there, so the level holds; otherwise the first stage accepts.

    Args:
        pool: the run's posterior-predictive rollouts (at least 5 successful; more are simulated on demand).
        cands: candidate effect instances (:func:`candidate_effects`); empty = the omnibus test alone.
        null: the run's trained task's replicates (:class:`~softsbi.workflows.criticism.check_null.CheckNull`): both
            statistics are then computed on the pool's first ``null.rollouts`` rollouts (the fit's evaluation
            samples, as each replicate's were) and combined against the replicates' pairs
            (:meth:`~softsbi.workflows.criticism.check_null.CheckNull.joint_p_value`); the null does not grow (the
            replicates set the resolution). Its family must be ``cands`` (:func:`~softsbi.workflows.criticism.
            check_null.run_check_null` checks it).

    Returns:
        ``(test, screening, ranking)``: the :class:`~softsbi.core.results.JointTest`, the :class:`Screening`
        (None without candidates or when the simulation at the posterior median failed) and its ranking.

    Raises:
        SoftsbiError: ``max_null`` cannot resolve ``alpha`` (:func:`check_resolution`); fewer than 5 successful
            posterior-predictive rollouts.
    """
    check_resolution(alpha, max_null)
    f_obs = run_features(pool.run, pool.run.dense)
    family = tuple(c.name for c in cands)

    def evaluate() -> tuple[JointTest, Screening | None, tuple[Candidate, ...]]:
        # a calibrated check: the rollouts the replicates were checked on (the fit's evaluation samples)
        rows = [k for k, r in enumerate(pool.rollouts) if null is None or r.sample < null.rollouts]
        feats = pool.features[rows]
        statistic, d_null = omnibus_statistics(f_obs, feats)
        omnibus = mc_pvalue(statistic, d_null) if null is None else null.p_value(statistic)
        screen, ranking, skipped = None, (), None if cands else "no candidate effects"
        if cands:
            try:
                screen = screening_of(pool, cands, unit_step, effect_step, feats)
                ranking = screen.ranking()
            except SoftsbiError as exc:  # e.g. the posterior median's simulation failed: the omnibus test alone,
                screen = None                # and every candidate in the table with the reason
                ranking = tuple(failed_candidate(c, f"not screened: {exc}") for c in cands)
                skipped = f"the screening failed: {exc}"
        top = next((c for c in ranking if c.screened), None)
        if top is None and skipped is None:
            skipped = f"none of the {len(cands)} candidates could be screened"
        combined = None
        if top is not None and screen is not None and screen.z_max is not None:
            pair = np.array([statistic, screen.z_obs_max])
            combined = (min_p_combined(pair, np.column_stack([d_null, screen.z_max])) if null is None
                        else null.joint_p_value(pair, list(screen.z_obs)))
        test = JointTest(omnibus=omnibus, directional=top.adjusted if top else None,
                         directional_effect=top.effect if top else None, family=family, alpha=alpha,
                         max_null=max_null, statistic=statistic, calibrated=null is not None,
                         directional_skipped=skipped, combined=combined,
                         directional_statistic=None if screen is None else screen.z_obs_max)
        return test, screen, ranking

    test, screen, ranking = evaluate()
    # a calibrated p-value's resolution is its replicates': more rollouts cannot change it
    joint = test.combined or test.omnibus
    if null is None and len(pool.rollouts) < max_null and resolution_needed(joint, alpha, max_null):
        pool.ensure_successful(max_null)  # the cap counts successful rollouts: failures would cost resolution
        test, screen, ranking = evaluate()
    return test, screen, ranking

    test, screen, ranking = evaluate()
    # a calibrated omnibus p-value's resolution is its replicates': more rollouts cannot change it, and once it
    # rejects alone more rollouts cannot change the verdict either (the omnibus p-value stays, the joint one falls)
    parts = [p for p in (None if null else test.omnibus, test.directional) if p is not None]
    if not test.misspecified and len(pool.rollouts) < max_null and any(
            resolution_needed(p, alpha / test.tests, max_null) for p in parts):
        pool.ensure_successful(max_null)  # the cap counts successful rollouts: failures would cost resolution
        test, screen, ranking = evaluate()
    return test, screen, ranking
