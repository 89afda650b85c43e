"""Each trained candidate's evidence from its own amortised posterior: the order in which ``diagnose`` refits.

On a task trained with its candidate models (``softsbi task train``), the posterior of the nominal model with effect
``E_k`` for a recording is that model's stored estimator conditioned on the recording: no simulation and no training,
exactly the first (and, on a trained task, only) round of ``E_k``'s refit. The summary energy score of its posterior
predictive, in the nominal fit's summary scale (:func:`~softsbi.workflows.criticism.statistics.summary_energy_score`, the score
:func:`~softsbi.workflows.criticism.decide.decide` compares refits on), is then an unbiased estimate of the score that refit
will have, at the cost of its ``n`` rollouts, for every trained candidate.

This is evidence that sees each candidate through its own model. The linearised screening
(:mod:`~softsbi.workflows.criticism.screening`) sees a candidate through a first-order expansion at the nominal posterior, so
an effect whose response is far from linear at the size the recording needs (a breeze that lifts a flap, a slope the
cloth slides down) can rank below one that is linear but wrong, and the refit budget then goes to the wrong one.
:func:`~softsbi.workflows.criticism.decide.refit_order` spends the budget on the amortised scores first; the screening orders
the candidates no task has trained.
"""
from __future__ import annotations

import zlib
from dataclasses import replace
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.core.errors import PosteriorError
from softsbi.core.results import Score
from softsbi.core.types import Recording
from softsbi.core.seeds import EVIDENCE_STREAM, surface_seed
from softsbi.inference.calibration import draws_in_box
from softsbi.workflows.fit.config import FitConfig, fit_param_space
from softsbi.workflows.fit.jobs import JobItem, run_jobs
from softsbi.workflows.fit.runs import RunView
from softsbi.workflows.criticism.stats import run_features, run_summarising
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
                 sims_per_round: int | None = None, workers: int | None = None) -> FitConfig:
    """The settings of ``run``'s refit with ``effects`` added: the nominal fit's (:meth:`FitConfig.from_run_config`)
    with the effects switched on, :data:`REFIT_PROPOSAL` proposals, no extra sensor draws (every refit observes each
    simulation once, physics and sensor effects alike), and its own rounds (None: the refit's own trained task when
    the nominal fit stopped at one, else the nominal fit's rounds) and simulations per round (None: the nominal
    fit's)."""
    base = run.config
    if rounds is None and not (run.report.per_round and run.report.per_round[0].task):
        rounds = base.rounds
    return replace(base, effects=list(run.effects) + list(effects), rounds=rounds,
                   sims_per_round=int(sims_per_round or base.sims_per_round), proposal=REFIT_PROPOSAL,
                   sensor_draws=0, workers=workers if workers is not None else base.workers)


def trained_task(run: RunView, effect: str) -> tuple[StoredTask, FitConfig, Any] | None:
    """The stored task of ``run``'s refit with ``effect`` added, its settings (resolved) and parameter space, when
    ``softsbi task train`` trained it (a training report, at least the refit's simulations per round) and the nominal
    fit stopped at its own trained task (a refit then stops at its task too); else None."""
    if not (run.report.per_round and run.report.per_round[0].task and run.report.rounds == 1):
        return None
    rec = recording_from_run(run)
    cfg = refit_config(run, [effect]).resolved(rec)
    _, space = fit_param_space(cfg, rec.scenario)
    prior = PriorRound.of(cfg, rec, space)
    if prior.task is None or not prior.trained(cfg.sims_per_round):
        return None
    return prior.task, cfg, space


def trained_tasks(run: RunView, effects: Sequence[str]) -> dict[str, tuple[StoredTask, FitConfig, Any]]:
    """:func:`trained_task` of each of ``effects`` that has one, by effect."""
    return {e: t for e in effects if (t := trained_task(run, e)) is not None}


def amortised_scores(run: RunView, trained: Mapping[str, tuple[StoredTask, FitConfig, Any]], scale: np.ndarray,
                     n: int, workers: int | None = None, seed: int = 0) -> tuple[dict[str, Score], int]:
    """The summary energy score of each trained candidate's amortised posterior predictive (module docstring).

    Args:
        run: the nominal fit (stopped at its trained task; otherwise nothing is scored).
        trained: the candidates with a trained task (:func:`trained_tasks`).
        scale: ``(F,)`` the nominal fit's summary scale (:func:`~softsbi.workflows.criticism.statistics.summary_scale`).
        n: posterior-predictive rollouts per candidate (``diagnose``'s ``n_null``: a refit's score uses as many).
        workers: simulation processes. seed: the draws' and rollouts' seed.

    Returns:
        ``{effect: Score}`` for the candidates scored (a candidate whose amortised posterior puts no mass in the
        prior box, or with fewer than ``MIN_NULL`` successful rollouts, is left out: its refit would fail or not
        be checked), and the number of rollouts simulated.

    Raises:
        SoftsbiError: an environment fault of the executor.
    """
    if not trained:
        return {}, 0
    f_obs = run_features(run, run.dense)
    items = []
    for effect, (task, cfg, space) in trained.items():
        fr = slice(None) if cfg.frames is None else list(cfg.frames)
        q = task.restore().posterior_at(run.x_obs[fr].astype(np.float64))
        stream = [seed, EVIDENCE_STREAM, zlib.crc32(effect.encode())]  # by name: the same whatever else is trained
        try:
            theta = space.from_unit(draws_in_box(q, n, np.random.default_rng(stream)))
        except PosteriorError:
            continue
        sim_seeds = np.random.default_rng(stream + [1]).integers(2**31, size=n)
        items.append((effect, cfg, space, [JobItem(t, int(s), summary_seed=surface_seed(i))
                                           for i, (t, s) in enumerate(zip(theta, sim_seeds))]))
    out: dict[str, Score] = {}
    for effect, cfg, space, jobs in items:
        ctx = replace(run_summarising(run, keep_rollout=False), effects=list(cfg.effects), param_names=space.names,
                      bank=None)
        res = run_jobs(ctx, jobs, workers, cfg.executor, cfg.executor_options,
                       label=f"{effect}: amortised posterior-predictive rollouts")
        feats = [r.features for r in res if r is not None and r.ok and r.features is not None]
        if len(feats) >= MIN_NULL:
            out[effect] = summary_energy_score(f_obs, np.array(feats), scale)
    return out, sum(len(jobs) for *_, jobs in items)

