"""Each trained candidate's evidence from its own amortised posterior: the order in which ``diagnose`` refits, and
the refit itself.

On a task trained with its candidate models (``softsbi task train``), the posterior of the nominal model with effect
``E_k`` for a recording is that model's stored estimator conditioned on the recording: no simulation and no training.
It is stored as ``E_k``'s refit run (:func:`amortised_refit`: a fit of the stored task's posterior alone, in the run
format ``compare``, ``view`` and ``check`` read, whose only simulations are its posterior-predictive rollouts), so on
a trained task the refit *is* the amortised posterior. The summary energy score of its posterior predictive, in the
nominal fit's summary scale (:func:`~softsbi.workflows.criticism.statistics.summary_energy_score`, the score
:func:`~softsbi.workflows.criticism.decide.decide` compares refits on), is then the score that refit has, at the
cost of its ``n`` rollouts, for every trained candidate (:func:`amortised_scores`); its check reuses them.

This is evidence that sees each candidate through its own model. The linearised screening
(:mod:`~softsbi.workflows.criticism.screening`) sees a candidate through a first-order expansion at the nominal posterior, so
an effect whose response is far from linear at the size the recording needs (a breeze that lifts a flap, a slope the
cloth slides down) can rank below one that is linear but wrong, and the refit budget then goes to the wrong one.
:func:`~softsbi.workflows.criticism.decide.refit_order` spends the budget on the amortised scores first; the screening orders
the candidates no task has trained.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.core.results import Gain, Score
from softsbi.core.store import RunStore
from softsbi.core.types import Param, ParamSpace, Recording
from softsbi.plugins import registry
from softsbi.workflows.fit.config import FitConfig, fit_param_space
from softsbi.workflows.fit.run import run_fit
from softsbi.workflows.fit.runs import RunView, final_posterior
from softsbi.workflows.criticism.decide import K_SE, improves
from softsbi.workflows.criticism.stats import PosteriorPredictive, run_features
from softsbi.workflows.criticism.statistics import MIN_NULL, summary_energy_score
from softsbi.workflows.fit.task_store import PriorRound, StoredTask

#: proposal of a refit: truncated (TSNPE, Deistler et al. 2022). A refit adds parameters to a model whose others the
#: nominal fit has already narrowed; truncated proposals spend its rounds inside the posterior's region, where the
#: corrected proposal's importance weights degenerate as the dimension grows
REFIT_PROPOSAL = "truncated"


def recording_from_run(run: RunView) -> Recording:
    """Rebuild the :class:`~softsbi.core.types.Recording` a run was fitted to."""
    return Recording(scenario=run.scenario, x=run.x_obs, dense=run.dense,
                     source=run.record.observed_source, truth=run.record.truth)


def refit_config(run: RunView, effects: Sequence[str], rounds: int | None = None,
                 sims_per_round: int | None = None, workers: int | None = None,
                 start: Mapping[str, Sequence[float]] | None = None) -> FitConfig:
    """The settings of ``run``'s refit with ``effects`` added: the nominal fit's (:meth:`FitConfig.from_run_config`)
    with the effects switched on, :data:`REFIT_PROPOSAL` proposals, no extra sensor draws (every refit observes each
    simulation once, physics and sensor effects alike), and its own rounds (None: the refit's own trained task when
    the nominal fit stopped at one, else the nominal fit's rounds) and simulations per round (None: the nominal
    fit's); ``start``: its first round's box (:attr:`FitConfig.start_box`, :func:`start_box`; None: the prior)."""
    base = run.config
    if rounds is None and not (run.report.per_round and run.report.per_round[0].task):
        rounds = base.rounds
    return replace(base, effects=list(run.effects) + list(effects), rounds=rounds,
                   sims_per_round=int(sims_per_round or base.sims_per_round), proposal=REFIT_PROPOSAL,
                   sensor_draws=0, workers=workers if workers is not None else base.workers,
                   start_box={k: [float(v[0]), float(v[1])] for k, v in (start or {}).items()})


#: posterior draws of each single refit that set a pair's start box (:func:`start_box`)
START_DRAWS = 4000
#: the posterior mass each single refit leaves outside its part of the box (TSNPE's default truncation, as the
#: sequential rounds use: :attr:`~softsbi.workflows.fit.config.FitConfig.truncation_eps`)
START_EPS = 1e-3
#: the box's padding per side, as a share of its width in the unit cube (as
#: :class:`~softsbi.core.distributions.TruncatedPrior` pads its bounding box)
START_PAD = 0.1


def start_box(singles: Sequence[Any]) -> dict[str, list[float]]:
    """A pair's first-round box (:attr:`~softsbi.workflows.fit.config.FitConfig.start_box`) from its singles'
    posteriors, so that the pair does not start from the prior at a single's budget.

    Each single refit (``singles``: :class:`~softsbi.core.results.Refit` of the pair's effects, one effect each)
    contributes, per parameter of its model, the central ``1 - START_EPS`` of :data:`START_DRAWS` draws of its final
    posterior (a refined refit's sequential one) in the unit cube; a parameter two singles share (the nominal
    model's) takes the union of their ranges, since with both effects on it may lie at either single's; each range
    is padded by :data:`START_PAD` of its width per side and clipped to the prior. A parameter no single infers (the
    effect of a pair's second candidate that was never refitted alone) is not named: it keeps its whole prior range.
    Returns ``{name: [low, high]}`` in physical units; empty without singles.

    The box is a truncated proposal (TSNPE, Deistler et al. 2022; box regions as in Miller et al. 2021): the
    pair's posterior is exact when the box holds its mass, which the union and the padding are there for; the
    later rounds truncate to the pair's own posterior, so a box that cut off mass is widened there.
    """
    lo: dict[str, float] = {}
    hi: dict[str, float] = {}
    params: dict[str, Param] = {}
    for i, refit in enumerate(singles):
        post = final_posterior(Path(refit.run), RunStore.open(Path(refit.run) / "run.zarr"))
        u = post.unit.sample(START_DRAWS, np.random.default_rng([START_DRAWS, i]))
        a, b = np.quantile(u, [START_EPS / 2, 1 - START_EPS / 2], axis=0)
        for j, p in enumerate(post.space):
            lo[p.name], hi[p.name] = min(lo.get(p.name, 1.0), a[j]), max(hi.get(p.name, 0.0), b[j])
            params.setdefault(p.name, p)
    if not params:
        return {}
    space = ParamSpace(list(params.values()))
    low, high = np.array([lo[n] for n in space.names]), np.array([hi[n] for n in space.names])
    pad = START_PAD * (high - low)
    u = np.stack([np.clip(low - pad, 0.0, 1.0), np.clip(high + pad, 0.0, 1.0)])
    theta = space.from_unit(u)
    return {n: [float(min(theta[0, j], theta[1, j])), float(max(theta[0, j], theta[1, j]))]
            for j, n in enumerate(space.names) if u[1, j] > u[0, j]}


def trained_task(run: RunView, effects: str | Sequence[str],
                 sims_per_round: int | None = None) -> tuple[StoredTask, FitConfig, Any] | None:
    """The stored task of ``run``'s refit with ``effects`` added (one effect's name, or several), its settings
    (resolved, ``sims_per_round`` None: the nominal fit's) and parameter space, when ``softsbi task train`` trained it
    (a training report, at least the refit's simulations per round) and the nominal fit stopped at its own trained
    task (a refit then stops at its task too); else None. Inside
    :func:`~softsbi.workflows.fit.task_store.read_once` the task is read once."""
    if not (run.report.per_round and run.report.per_round[0].task and run.report.rounds == 1):
        return None
    rec = recording_from_run(run)
    cfg = refit_config(run, [effects] if isinstance(effects, str) else list(effects), None,
                       sims_per_round).resolved(rec)
    _, space = fit_param_space(cfg, rec.scenario)
    prior = PriorRound.of(cfg, rec, space)
    if prior.task is None or not prior.trained(cfg.sims_per_round):
        return None
    return prior.task, cfg, space


def trained_tasks(run: RunView, effects: Sequence[str]) -> dict[str, tuple[StoredTask, FitConfig, Any]]:
    """:func:`trained_task` of each of ``effects`` (one effect each) that has one, by effect."""
    return {e: t for e in effects if (t := trained_task(run, e)) is not None}


def uninformed_candidates(trained: Mapping[str, tuple[StoredTask, FitConfig, Any]]) -> dict[str, float]:
    """The trained candidates (``trained``: :func:`trained_tasks`) that their task does not inform: on the task's
    held-out prior simulations (``task train``'s training report) the median 90% interval of every one of the
    effect's own parameters spans more than :data:`~softsbi.inference.contraction.INFORMED_MAX_RATIO` of the
    prior's width. The data of such a task mostly leave the effect's posterior near its prior, so its off value is
    seldom excluded (:func:`~softsbi.workflows.criticism.diagnose.may_be_off`) and the diagnosis seldom names it. By
    effect: the smallest of those width ratios. A task without a training report says nothing (left out)."""
    out = {}
    for effect, (task, _, _) in trained.items():
        if task.report is None:
            continue
        own = {p.name for p in registry().effect(effect)().param_space()}
        entries = [c for n, c in task.report.contraction.items() if n in own]
        if entries and not any(c.informed for c in entries):  # each decided by the report, at INFORMED_MAX_RATIO
            out[effect] = float(min(c.width_ratio for c in entries))
    return out


def refit_dir(root: str | Path, effects: Sequence[str], sequential_of_trained: bool = False) -> Path:
    """The folder of ``effects``' refit under ``root`` (the nominal run's directory or ``diagnose --out``):
    ``refit-<a>+<b>``; a sequential refit of a model that has a trained task (``--refit-rounds N``) keeps apart from
    its amortised one, in ``refit-<a>+<b>-sequential``, since neither run can resume the other."""
    return Path(root) / f"refit-{'+'.join(effects)}{'-sequential' if sequential_of_trained else ''}"


def amortised_refit(run: RunView, effects: Sequence[str], root: str | Path, workers: int | None = None,
                    plots: bool = False, callbacks: Any = None) -> Path:
    """Store the amortised posterior of the nominal model with ``effects`` (its trained task's estimator
    conditioned on ``run``'s recording) as that model's refit run, :func:`refit_dir` under ``root``: a fit of the
    stored task's posterior alone (:func:`~softsbi.workflows.fit.run.run_fit`'s ``task_only``) at
    :func:`refit_config`'s settings, so that ``compare``, ``view`` and ``check`` read it as any refit. Its only
    simulations are its posterior-predictive rollouts, :data:`RACE_START` of them (``n_eval``; its check and score
    extend them), and its best fit's; a stored one is resumed (read).
    ``plots``: draw its fit figures. Returns the folder.

    Raises:
        SoftsbiError: the model has no trained task (:func:`trained_task`). PosteriorError: the amortised posterior
            puts no mass in the prior box. Everything :func:`~softsbi.workflows.fit.run.run_fit` raises.
    """
    cfg = refit_config(run, effects, None, None, workers)
    cfg = replace(cfg, n_eval=min(cfg.n_eval, RACE_START))  # its score's race starts there (:func:`amortised_scores`)
    out = refit_dir(root, effects)
    run_fit(out, recording_from_run(run), cfg, callbacks=callbacks, make_plots=plots, task_only=True)
    return out


#: posterior-predictive rollouts every trained candidate's amortised score starts with in :func:`amortised_scores`'s
#: race; an undecided candidate's rollouts double, up to ``diagnose``'s ``n_null`` (at 10 and 30: stages of 10, 20,
#: 30). Its energy score is unbiased at any size (:func:`~softsbi.workflows.criticism.statistics.summary_energy_score`),
#: so a score on fewer rollouts differs only in its standard error
RACE_START = 10


def amortised_scores(run: RunView, pools: Mapping[str, PosteriorPredictive], scale: np.ndarray, n: int,
                     nominal: Score | None = None, keep: int = 0, k_se: float = K_SE,
                     start: int = RACE_START) -> tuple[dict[str, Score], int]:
    """The summary energy score of each trained candidate's amortised posterior predictive (module docstring), each
    on the rollouts its refit decision needs: a race (successive elimination, Maron & Moore 1994).

    Every candidate is scored on ``start`` rollouts. At each stage a candidate leaves the race, keeping the score it
    has, when its decision is made either way:

    - *futile*: its gain over ``nominal`` could not reach ``k_se`` standard errors at ``n`` rollouts even if its
      true gain were ``k_se`` of its present standard errors above its estimate (the standard error shrinks as
      ``1/sqrt(rollouts)``: ``z_m < k_se (sqrt(m/n) - 1)`` at ``m`` rollouts), so
      :func:`~softsbi.workflows.criticism.decide.refit_order` will not refit it;
    - *outranked*: ``keep`` other candidates improve on ``nominal`` by ``k_se`` standard errors and score lower
      than it by ``k_se`` standard errors of the difference, so the ``keep`` refits go to others first.

    The others get twice as many rollouts, up to ``n``, where every candidate left is scored as without the race.
    ``nominal`` None or ``keep`` 0: no race (every candidate on ``n`` rollouts).

    Args:
        run: the nominal fit (stopped at its trained task).
        pools: each candidate's amortised refit's posterior-predictive rollouts (:func:`amortised_refit`, then
            :class:`~softsbi.workflows.criticism.stats.PosteriorPredictive`), by effect; its check shares them.
        scale: ``(F,)`` the nominal fit's summary scale (:func:`~softsbi.workflows.criticism.statistics.summary_scale`).
        n: posterior-predictive rollouts per candidate at most (``diagnose``'s ``n_null``: a refit's score uses as
            many).
        nominal: the nominal fit's score in ``scale``; keep: the refits the decision spends (``confirm``); k_se:
            the decision's margin (:data:`~softsbi.workflows.criticism.decide.K_SE`); start: the first stage's
            rollouts (:data:`RACE_START`).

    Returns:
        ``{effect: Score}`` for the candidates scored (each with the rollouts it was scored on; one with fewer than
        ``MIN_NULL`` successful rollouts is left out: its refit would not be checked), and the number of rollouts
        requested.

    Raises:
        SoftsbiError: an environment fault of the executor.
    """
    f_obs = run_features(run, run.dense)
    out: dict[str, Score] = {}
    live = dict(pools)
    m = n if nominal is None or keep <= 0 else min(max(start, MIN_NULL), n)
    while live:
        for effect, pool in live.items():
            feats = pool.ensure(m).features[:m]
            if len(feats) >= MIN_NULL:
                out[effect] = summary_energy_score(f_obs, feats, scale)
        if m >= n:
            break
        live = {e: p for e, p in live.items() if e in out and not decided(e, out, nominal, keep, k_se, m / n)}
        m = min(2 * m, n)
    return out, sum(pool.requested for pool in pools.values())


def decided(effect: str, scores: Mapping[str, Score], nominal: Score, keep: int, k_se: float,
            fraction: float) -> bool:
    """Whether ``effect``'s refit decision is made at ``fraction`` of its rollouts (:func:`amortised_scores`: futile
    or outranked)."""
    g = Gain.of(nominal, scores[effect])
    if g is not None and g.z < k_se * (np.sqrt(fraction) - 1):
        return True
    c = scores[effect]
    ahead = [s for e, s in scores.items() if e != effect and improves(nominal, s, k_se)
             and c.value - s.value > k_se * np.hypot(c.se, s.se)]
    return len(ahead) >= keep
