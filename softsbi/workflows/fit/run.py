"""The sequential real-to-sim fit (BayesSim, Ramos et al. 2019; Antonova et al. 2022, Alg. 1).

Round 1 draws ``sims_per_round`` parameters from the prior; round r+1 draws them from the
prior truncated to round r's posterior (the default, TSNPE,
:class:`~softsbi.core.distributions.TruncatedPrior`), or with ``proposal="corrected"`` (the
paper's BayesSim rounds) from the corrected posterior of round r
(:class:`~softsbi.core.distributions.PosteriorChain`). Estimators with ``sequential = False``,
the "bulk" baselines, draw every round from the prior and their posterior is ``q`` truncated
to the prior box, so round r reports the bulk method with r x sims_per_round simulations. All
simulations are kept; after each round the estimator is trained on all usable simulations
so far and conditioned on the observation. Everything goes to the run's Zarr store as it
is produced, so :func:`run_fit` on an existing run directory resumes where it stopped.

This module resolves simulators, observers, estimators and executors by *name* through
the plugin registry: it imports no simulator. :class:`FitConfig` is the one set of settings
(and defaults) of the CLI's ``fit`` and the Python API.

This module runs the steps; each lives in its own module: the settings in
:mod:`~softsbi.workflows.fit.config`, what the fit sees in :mod:`~softsbi.workflows.fit.observe`, opening and
repairing a stored run in :mod:`~softsbi.workflows.fit.resume`, the rounds in :mod:`~softsbi.workflows.fit.rounds`,
``report.json`` in :mod:`~softsbi.workflows.fit.report_file`. The names callers use stay importable from here (``__all__``).
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.distributions import PosteriorChain, RoundPosterior
from softsbi.core.errors import SoftsbiError
from softsbi.core.results.fitreport import FitReport
from softsbi.core.results import check_result_path, write_json_atomic
from softsbi.core.store import RunStore
from softsbi.core.store.groups import holds
from softsbi.core.types import STATUS_ERROR, ParamSpace, Recording
from softsbi.core.seeds import eval_stream
from softsbi.plugins import registry
from softsbi.workflows.fit.plots import FIGURES, write_fit_plots
from softsbi.workflows.fit.bank import BankCount, banks_enabled, check_bank_path
from softsbi.workflows.fit.bestfit import REFINE, best_stored, refine, store_best_fit
from softsbi.workflows.fit.config import FitConfig, RunRecord, estimator_options, fit_param_space, parameter_table
from softsbi.workflows.fit.report_file import ChamferStats, build_report, chamfer_stats, damaged_report, read_report
from softsbi.workflows.fit.jobs import JobItem, JobResult, SimContext, evaluation_seeds, map_simulations, simulate_job
from softsbi.core import defaults
from softsbi.workflows import pools
from softsbi.workflows.lock import run_lock
from softsbi.workflows.fit.observe import fit_sim_context, metric_sensor, observer_options
from softsbi.workflows.reporting import FitCallbacks
from softsbi.workflows.fit.resume import RunClock, open_store, repair_damaged, retry_failed_simulations
from softsbi.workflows.fit.rounds import Rounds, SensorDraws, round_posterior, tell_bank
from softsbi.workflows.fit.task_store import PriorRound
from softsbi.workflows.fit.prior_widening import (decide_widening, map_mixture, prior_of_record, reconcile, records, space_of_round,
                                     unit_map, widening_sentence)

#: what callers import from here besides :func:`run_fit` (defined in the step modules; ``softsbi.workflows.fit.run``
#: stays the one import path of a fit's API)
__all__ = ["FitCallbacks", "FitConfig", "FitResult", "JobItem", "JobResult", "SensorDraws", "SimContext",
           "chamfer_stats", "estimator_options", "fit_param_space", "metric_sensor", "observer_options",
           "parameter_table", "read_report", "round_posterior", "run_fit", "simulate_job"]


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`run_fit`; ``report`` is ``report.json``, typed (``report.to_json()`` is the file's object).

    ``posterior`` samples theta in unit coordinates (``param_space.from_unit`` maps them to
    physical units); :func:`softsbi.open_run` gives the posterior in physical units."""

    store: RunStore
    param_space: ParamSpace
    posterior: RoundPosterior
    report: FitReport


def run_fit(out_dir: str | Path, recording: Recording, cfg: FitConfig | None = None,
            callbacks: FitCallbacks | None = None, make_plots: bool = True, retry_failed: bool = False,
            task_only: bool = False) -> FitResult:
    """Run (or resume) a sequential fit into ``out_dir``.

    Writes ``out_dir/run.zarr`` as it goes, then ``report.json`` and PNGs.

    Args:
        out_dir: run directory; if it holds a run with the same settings, the fit resumes after
            the last completed step (finished simulations are never redone).
        recording: what to fit (a real recording or a simulated one).
        cfg: settings (default :class:`FitConfig`()); ``cfg.rounds`` may be raised on resume to
            add rounds.
        callbacks: progress callbacks (:class:`FitCallbacks`).
        retry_failed: on resume, simulate the stored failed simulations again (e.g. after fixing the
            environment that made them fail): the earliest round with failures is redone from its
            stored draws and the rounds after it are drawn again from its new posterior.
        task_only: a fit of a task ``softsbi task train`` trained, in one round: the stored task's posterior
            conditioned on the recording, with no simulation of the first round's own (a fit that stops at the
            trained task reads its prior simulations back from the bank, for the report's prior Chamfer and the
            best fit among them; this one draws none, so its report has no prior Chamfer). Its evaluation
            rollouts and best fit are simulated as any fit's. What a refit of a trained candidate stores
            (``diagnose``); a run begun this way stays so when it is resumed.

    Returns:
        :class:`FitResult`.

    Raises:
        RunLocked: another process is writing ``out_dir`` (one writer per run directory).
        SchemaError: the run directory holds a run with incompatible settings or schema.
        PluginNotFound, ParameterError: bad plugin names, effects or bounds.
        EnvironmentFault: the machine cannot simulate; nothing is stored as failed.
        PosteriorError: a round's posterior has no mass in the prior box.
        SoftsbiError: a simulation bank that is empty, a file, cannot be created, or lies inside or around
            ``out_dir`` or the recording (:func:`~softsbi.workflows.fit.bank.check_bank_path`); ``task_only``
            without a task trained for ``cfg``'s first round, or with more than one round.
    """
    callbacks = callbacks or FitCallbacks()
    cfg = (cfg or FitConfig()).resolved(recording)
    cfg.validate()
    observed = recording.source if recording.source and Path(recording.source).is_dir() else None
    check_bank_path(cfg.sim_bank, {"--out": out_dir, "--observed": observed})
    with run_lock(out_dir), pools.shared_executors():
        for name in ("report.json", *(FIGURES if make_plots else ())):  # a folder in a file's place: refused
            check_result_path(Path(out_dir) / name)                        # before any simulation
        return _run_fit_locked(Path(out_dir), recording, cfg, callbacks, make_plots, retry_failed, task_only)


def _run_fit_locked(out_dir: Path, recording: Recording, cfg: FitConfig, callbacks: FitCallbacks, make_plots: bool,
                    retry_failed: bool, task_only: bool = False) -> FitResult:
    """:func:`run_fit` with the run directory's lock held."""
    reg = registry()
    est_cls = reg.estimator(cfg.estimator)
    reg.executor(cfg.executor)  # an unknown executor fails before any work
    _, base = fit_param_space(cfg, recording.scenario)
    space = prior_of_record(out_dir / "run.zarr", base)  # a --widen fit's widened prior
    prior = PriorRound.of(cfg, recording, base)  # the first round as a stored task (:mod:`.tasks`)
    if prior.damaged is not None:
        callbacks.message(prior.damage_line())
    if task_only:
        if not prior.trained(cfg.sims_per_round) or cfg.rounds not in (None, 1):
            raise SoftsbiError(f"a fit of the stored task's posterior alone takes one round of a task `softsbi task "
                               f"train` trained for its settings (rounds {cfg.rounds}; "
                               f"{'a trained task' if prior.trained(cfg.sims_per_round) else 'no trained task'})")
        cfg = replace(cfg, rounds=1)
    if cfg.rounds is None:  # a trained task's posterior alone, else the sequential rounds
        cfg = replace(cfg, rounds=1 if prior.trained(cfg.sims_per_round) else defaults.ROUNDS)
    store, prev = open_store(out_dir, recording, cfg, space, callbacks)
    damaged = damaged_report(out_dir)
    if damaged is not None:
        callbacks.message(f"{damaged}: this fit resumes the run and writes it again")
    clock = RunClock(store, prev)
    repair_damaged(store, callbacks)
    if retry_failed:
        retry_failed_simulations(store, callbacks)
    space = reconcile(store, base, callbacks.message)
    ctx = fit_sim_context(cfg, recording, store, space)
    loop = Rounds(cfg, store, space, ctx, est_cls, callbacks, clock, prior, task_only)
    try:
        with pools.executor(cfg.executor, cfg.workers, cfg.executor_options) as executor:
            for r in range(cfg.rounds):
                loop.space = space_of_round(base, store.config, r)
                loop.run_round(r, executor)
                _next_prior(loop, base, r)
            space = loop.space
            post = loop.chain.posterior(len(loop.chain) - 1)
            ev_stats = _evaluate(store, post, space, ctx, executor, cfg, callbacks)
            loop.summaries[-1]["chamfer_posterior"] = ev_stats
            best = _best_fit(store, post, space, ctx, executor, cfg, callbacks) if loop.scored else None
    finally:
        with contextlib.suppress(OSError):  # also when interrupted: the next session's resume message counts it
            clock.save(force=True)
    samples = space.from_unit(post.sample(4000, np.random.default_rng([cfg.seed, 99])))
    wall = clock.save(force=True)
    report = build_report(recording, cfg, space, loop, ev_stats, samples, wall,
                          RunRecord.from_run_config(store.config).metric)
    report.update(best_fit=best, widened=records(store.config))
    write_json_atomic(out_dir / "report.json", report)
    if damaged is not None:
        callbacks.message(f"rewrote {damaged.path}, which was damaged ({damaged.problem})")
    result = FitResult(store=store, param_space=space, posterior=post,
                       report=FitReport.from_json(report, out_dir / "report.json"))
    if make_plots:
        write_fit_plots(out_dir, result, recording, cfg, samples,
                        observer_options=observer_options(cfg, recording.scenario))
    return result


def _next_prior(loop: Rounds, base: ParamSpace, r: int) -> None:
    """After round ``r``: with ``--widen`` (and a round to follow) widen the bounds its posterior presses unless
    the run already decided after this round (:func:`~softsbi.workflows.fit.prior_widening.decide_widening`); then, when round ``r + 1``
    draws in another prior, express the posterior its proposal truncates to in that prior's unit cube."""
    cfg, store = loop.cfg, loop.store
    if r + 1 >= cfg.rounds:
        return
    if cfg.widen and not any(int(w["after_round"]) == r for w in records(store.config)):
        post = loop.chain.posterior(len(loop.chain) - 1)
        samples = loop.space.from_unit(post.sample(4000, np.random.default_rng([cfg.seed, 99, r])))
        keep = {k: v for e in cfg.effects for k, v in registry().effect(e)().nominal().items()}
        if decide_widening(store, loop.space, samples, r, keep) is not None:
            loop.cb.message(widening_sentence(records(store.config)[-1]))
    nxt = space_of_round(base, store.config, r + 1)
    if nxt != loop.space:
        q, count = loop.chain.qs[-1], loop.chain.counts[-1]
        loop.chain = PosteriorChain(nxt.dim, seed=cfg.seed)
        loop.chain.add_round(map_mixture(q, *unit_map(loop.space, nxt)), count)
        loop.space = nxt


def _best_fit(store: RunStore, post: RoundPosterior, space: ParamSpace, ctx: SimContext, executor: Any,
              cfg: FitConfig, hooks: FitCallbacks) -> dict[str, Any] | None:
    """``report.json``'s ``best_fit``: the best of the fit's simulations, after ``cfg.refine`` more by CMA-ES
    from the posterior (:mod:`~softsbi.workflows.fit.bestfit`), with its rollout stored in the run."""
    rec = RunRecord.from_run_config(store.config)
    frames, metric = rec.metric_frames, rec.metric
    refined = None
    if cfg.refine > 0:
        before = best_stored(store, cfg.rounds, cfg.seed, frames)
        mean, cov = post.moments(20000, seed=cfg.seed + 20_000)
        have = len(store.read_rows(REFINE)[0]["status"]) if store.has(REFINE) else 0
        hooks.round_start(-2, cfg.rounds, max(cfg.refine - have, 0), cfg.refine)
        refined = refine(store, space, mean, cov, ctx, executor, cfg.refine, cfg.seed, cfg.rounds, frames,
                         progress=lambda d, n: hooks.simulation_done(-2, d, n), message=hooks.message)
        refined.update(requested=cfg.refine, start_mean=space.as_dict(space.from_unit(mean)),
                       best_before=None if before is None else before["score"])
    best = best_stored(store, cfg.rounds, cfg.seed, frames, cfg.refine)
    if best is None:
        return None
    stored = store_best_fit(store, best, space, ctx, executor, cfg.fixed)
    return {"theta": space.as_dict(best["theta"]), metric: best["score"],
            metric.replace("_m", "_per_frame_m").replace("_px", "_per_frame_px"): best["chamfer"].tolist(),
            "source": best["source"], "simulation": best["index"], "seed": best["seed"],
            "simulations_searched": best["simulations"], "rollout": "run.zarr/best_fit" if stored else None,
            "refine": refined}


def _evaluate(store: RunStore, post: RoundPosterior, space: ParamSpace, ctx: SimContext, executor: Any,
              cfg: FitConfig, hooks: FitCallbacks) -> ChamferStats:
    """Rollouts at ``cfg.n_eval`` final-posterior samples (stored under ``evaluation/``) and their Chamfer summary."""
    if store.has("evaluation"):
        arrays, attrs = store.read_group("evaluation")
        if holds(attrs, {"rounds": cfg.rounds}) and len(arrays["status"]) == cfg.n_eval:
            frames = RunRecord.from_run_config(store.config).metric_frames
            return chamfer_stats(arrays["chamfer"], arrays["status"], frames, arrays.get("chamfer_one_sided"))
    rng = np.random.default_rng([cfg.seed, eval_stream(cfg.rounds)])
    u = post.sample(cfg.n_eval, rng)
    theta = space.from_unit(u)
    seeds = evaluation_seeds(cfg.seed, cfg.rounds, cfg.n_eval)
    T = len(ctx.scenario["times"])
    chamfer = np.full((cfg.n_eval, T), np.nan)
    one_sided = np.full((cfg.n_eval, T), np.nan)
    status = np.full(cfg.n_eval, STATUS_ERROR, np.uint8)
    hooks.round_start(-1, cfg.rounds, cfg.n_eval, cfg.n_eval)
    done = 0
    # the run's own bank: check, diagnose, compare and view re-simulate these rollouts first (RunView.sim_context)
    bank = str(store.path.parent / "sims.zarr") if banks_enabled() and ctx.ref_masks is None else None
    count = BankCount()
    for i, res in map_simulations(executor, replace(ctx, bank=bank), [JobItem(t, s) for t, s in zip(theta, seeds)]):
        done += 1
        hooks.simulation_done(-1, done, cfg.n_eval)
        if isinstance(res, SoftsbiError):  # an environment fault: stop, nothing stored
            raise res
        if isinstance(res, BaseException):
            continue
        count.add(res.bank)
        status[i] = res.status
        if res.chamfer is not None:
            chamfer[i] = res.chamfer
        if res.chamfer_one_sided is not None:
            one_sided[i] = res.chamfer_one_sided
    tell_bank(hooks, -1, count, cfg.n_eval, bank)
    arrays = {"theta": theta, "u": u, "status": status, "chamfer": chamfer}
    if ctx.ref_masks is None:
        arrays["chamfer_one_sided"] = one_sided
    store.write_group("evaluation", arrays,
                      attrs={"rounds": cfg.rounds, "what": "rollouts at final-posterior samples"},
                      units={"chamfer": "px" if ctx.ref_masks is not None else "m", "chamfer_one_sided": "m",
                             "theta": "physical"})
    return chamfer_stats(chamfer, status, RunRecord.from_run_config(store.config).metric_frames,
                         one_sided if ctx.ref_masks is None else None)
