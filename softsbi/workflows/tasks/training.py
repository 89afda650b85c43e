"""``softsbi task train``: train a task once (:mod:`~softsbi.workflows.fit.task_store`), for the model and each candidate effect.

For each model (the nominal model, then the nominal model with each candidate effect switched on):

1. ``n_prior`` parameters are drawn from the prior exactly as a fit's first round draws them (unit cube
   ``[seed, 0, 0]``, seeds ``[seed, 0, 1]``), simulated through the simulation bank (a fit's first round then reads
   them) and observed with the fit's observer and sensor model;
2. the fit's estimator is trained on them as a fit's first round trains it (same options, seed ``seed``);
3. ``n_test`` held-out prior simulations (seeds of their own, never trained on) measure the amortised posterior:
   expected coverage, SBC ranks per parameter and TARP, one verdict over them
   (:func:`~softsbi.workflows.tasks.calibrate.calibration_stats`), and the contraction per parameter (the posterior's
   90% interval over the prior's, :mod:`~softsbi.inference.contraction`, median over the test pairs);
4. the task is stored under its key with that training report.

A model whose task ``task train`` stored with at least ``n_prior`` prior simulations and a training report (or
without one, when ``n_test`` is 0) is not trained again (``retrain=True`` does). The prior held-out simulations go
through the bank too, so a retrained task re-simulates nothing.
"""
from __future__ import annotations

import os
import time
from dataclasses import replace
from typing import Any, Callable, Sequence

import numpy as np

from softsbi.core.errors import SoftsbiError, storage_error
from softsbi.core.results.fitreport import TrainingReport
from softsbi.core.jsonfile import check_result_path
from softsbi.core.store.posterior import EstimatorState
from softsbi.core.types import ParamSpace, Recording
from softsbi.core.seeds import TEST_STREAM
from softsbi.inference.contraction import INFORMED_MAX_RATIO
from softsbi.plugins import registry
from softsbi.core import defaults
from softsbi.workflows import pools
from softsbi.workflows.reporting import duration_words
from softsbi.workflows.tasks.calibrate import calibration_stats, coverage_json, rank_histograms_json
from softsbi.workflows.criticism.check_null import NULL_FILE, check_replicates, stored_check_null, train_check_null
from softsbi.workflows.fit.config import FitConfig, estimator_options, fit_param_space, needs_images
from softsbi.workflows.fit.jobs import JobItem, SimContext, _round_seeds, prior_unit_draws, run_jobs, sensor_parameters
from softsbi.workflows.criticism.screening import default_candidates, is_generic, screening_size
from softsbi.workflows.criticism.switched_on import store_off_null, stored_off_null, train_off_null, unit_off_values
from softsbi.workflows.fit.task_store import TASK_TRAIN_INFO, PriorRound, StoredTask, first_round_context



def candidate_models(cfg: FitConfig, names: Sequence[str] | None) -> list[list[str]]:
    """The models a task trains: the nominal model (``cfg.effects``) and, per candidate effect, the nominal model
    with it switched on. ``names`` None: every installed non-generic effect the backend applies (what ``diagnose``
    refits); ``[]``: the nominal model only.

    Raises:
        SoftsbiError: a named effect the backend cannot apply, or one named twice."""
    reg = registry()
    twice = sorted({n for n in names or [] if list(names).count(n) > 1})
    if twice:
        raise SoftsbiError(f"--candidates names {', '.join(twice)} more than once: each model is trained once; name "
                           f"each candidate once")
    sim_cls = reg.simulator(cfg.backend)
    if names is None:
        names = [n for n in sim_cls.effects if n in reg.tables["effect"] and not is_generic(reg.effect(n)())]
    bad = [n for n in names if sim_cls.supports(reg.effect(n)) is not None]
    if bad:
        raise SoftsbiError(f"--candidates: backend '{cfg.backend}' cannot apply {bad}; it applies "
                           f"{list(sim_cls.effects)}")
    return [list(cfg.effects)] + [list(cfg.effects) + [n] for n in names if n not in cfg.effects]


def _simulate(ctx: SimContext, space: ParamSpace, u: np.ndarray, seeds: np.ndarray, cfg: FitConfig,
              label: str) -> tuple[np.ndarray, np.ndarray]:
    """``(U, X)``: the usable ones of the simulations at unit-cube ``u`` with ``seeds`` (status ok, finite)."""
    items = [JobItem(theta, seed) for theta, seed in zip(space.from_unit(u), seeds.tolist())]
    res = run_jobs(ctx, items, workers=cfg.workers, executor=cfg.executor, executor_options=cfg.executor_options,
                   label=label)
    ok = [i for i, r in enumerate(res) if r.ok and r.x is not None and np.all(np.isfinite(r.x))]
    if not ok:
        reasons = sorted({str(r.reason) for r in res})[:3]
        raise SoftsbiError(f"{label}: every simulation failed, e.g. {reasons}; narrow the prior with --bounds")
    return u[ok], np.stack([res[i].x for i in ok])


def train_model(recording: Recording, cfg: FitConfig, n_prior: int, n_test: int = defaults.N_TEST,
                n_draws: int = defaults.N_DRAWS, retrain: bool = False, check_null: int = 0,
                message: Callable[[str], None] | None = None, screened: Sequence[str] | None = ()) -> StoredTask:
    """Train one model's task (module docstring) and store it; returns the stored task.

    Args:
        recording: a recording of the task (its scenario and sensor settings; its observation is not used).
        cfg: the fit's settings (``cfg.effects`` the model).
        n_prior: prior simulations trained on. n_test: held-out prior simulations of the report (0: no report).
        n_draws: posterior draws per held-out simulation. retrain: train even when the task is stored.
        check_null: replicate recordings that calibrate ``check`` of the task's fits
            (:func:`~softsbi.workflows.criticism.check_null.train_check_null`, on ``defaults.N_NULL`` rollouts each; 0: none),
            computed when the task has none for these settings.
        message: progress notices.
        screened: candidates the replicates are screened against besides the model's default family (the task's
            trained candidates: a diagnosis may name them), so that a check against any part of them is calibrated;
            None: the replicates are not screened and calibrate the omnibus test alone (a candidate model's, which
            calibrate the adequacy check of its refit).

    Raises:
        SoftsbiError: no simulation bank (tasks are stored beside it), ``--sensor-draws``, an image observer, a task
            store that cannot be written (before any simulation; StorageError "no space left on the device" for a
            full disk, also when it fills up during the training), or every simulation failed. PosteriorError: the
            estimator puts no mass in the prior box.

    Another process training the same task holds its lock (:meth:`~softsbi.workflows.fit.task_store.TaskStore.lock`):
    this one says so, waits, and reuses what it stored.
    """
    say = message or (lambda s: None)
    t_start = time.perf_counter()
    cfg, space, ctx, prior = _prepared(recording, cfg)
    model = "+".join(["nominal", *cfg.effects])
    prior.store.check_writable()  # a store that cannot take the task refuses now, not after the training

    def waiting() -> None:
        say(f"{model}: task {prior.digest[:12]} is being trained by another process; waiting for it to finish "
            f"(its stored task is then reused here)")

    with prior.store.lock(prior.digest, waiting):  # one process trains a task; a second one waits for it
        prior = PriorRound.of(cfg, recording, space)  # read again: the other process may have stored it
        task = prior.task
        if prior.damaged is not None:
            say(f"{model}: stored task {prior.damaged.digest[:12]} is damaged ({prior.damaged.problem}): training it "
                f"again in its place")
        if task is not None and task.by_task_train and (task.report is not None or not n_test) and \
                task.n_prior >= n_prior and not retrain:
            say(f"{model}: stored task {task.digest[:12]} ({task.n_prior} prior simulations) reused")
        else:
            task = _train(recording, cfg, space, ctx, prior, model, n_prior, n_test, n_draws, say, t_start)
    return _with_check_null(task, recording, cfg, space, ctx, check_null, say, screened)


def _train(recording: Recording, cfg: FitConfig, space: ParamSpace, ctx: SimContext, prior: PriorRound, model: str,
           n_prior: int, n_test: int, n_draws: int, say: Callable[[str], None], t_start: float) -> StoredTask:
    """:func:`train_model`'s steps 1-4 for a model not stored yet (its task's lock held)."""
    est_cls = registry().estimator(cfg.estimator)
    opts = estimator_options(cfg, est_cls)
    ctx = replace(ctx, bank=str(prior.store.path.parent))
    u = prior_unit_draws([cfg.seed, 0, 0], n_prior, space.names, sensor_parameters(cfg.backend, cfg.effects))
    U, X = _simulate(ctx, space, u, _round_seeds(cfg.seed, 0, n_prior), cfg, f"{model}: prior simulations")
    fr = slice(None) if cfg.frames is None else list(cfg.frames)
    say(f"{model}: training '{cfg.estimator}' on {len(U)} prior simulations")
    t0 = time.perf_counter()
    est = est_cls(**opts)
    info = est.fit(U.astype(np.float64), X[:, fr].astype(np.float64), seed=cfg.seed)
    info = dict(info, n_train_total=int(len(U)), usable_per_round=[int(len(U))], sensor_pairs=0,
                **{TASK_TRAIN_INFO: True})  # a task trained here, with or without its report: no fit's
    report = None
    if n_test > 0:
        report = training_report(est, ctx, space, cfg, n_test, n_draws, fr)
        report = replace(report, train_seconds=time.perf_counter() - t0 - report.simulation_seconds,
                         wall_seconds=time.perf_counter() - t_start)  # prior and held-out simulations, training
    try:
        stored = prior.store.put(prior.identity, n_prior, _state(est, cfg.estimator, opts), info, report, strict=True)
    except OSError as exc:  # e.g. the disk filled up during the training: the models stored before are kept
        raise storage_error(exc, prior.store.path, out_flag="--sim-bank") or SoftsbiError(
            f"the task store {prior.store.path} cannot be written ({exc.strerror or exc}): give --sim-bank a folder "
            f"you can write; the models stored before this one are kept") from None
    if stored is None:
        raise SoftsbiError(f"the task store {prior.store.path} cannot be read back after storing {model}: give "
                           f"--sim-bank a folder you can write")
    return stored


def _prepared(recording: Recording, cfg: FitConfig) -> tuple[FitConfig, ParamSpace, SimContext, PriorRound]:
    """One model's settings (resolved, one round), parameter space, first-round context and prior round.

    Raises:
        SoftsbiError: an image observer, ``--sensor-draws``, or no simulation bank (tasks are stored beside it)."""
    cfg = replace(cfg.resolved(recording), rounds=1)
    cfg.validate()
    if needs_images(cfg):
        raise SoftsbiError("task train takes point-cloud fits; an image observer's fits train per recording")
    if cfg.sensor_draws:
        raise SoftsbiError("task train does not take --sensor-draws: its extra observations are drawn per round")
    _, space = fit_param_space(cfg, recording.scenario)
    prior = PriorRound.of(cfg, recording, space)
    if prior.store is None:
        raise SoftsbiError("stored tasks live in the simulation bank, which is off: give --sim-bank DIR (or unset "
                           "SOFTSBI_SIM_BANK=off)")
    return cfg, space, first_round_context(cfg, recording, space), prior


def pilot_seconds(recording: Recording, cfg: FitConfig) -> float | None:
    """The wall time (s) of one simulation of the nominal model in a warm worker: the first two of its prior draws
    simulated one after the other in one process, outside the simulation bank (a bank read measures no
    simulation; nothing is stored), and the second one's time. The first one's includes the worker's start-up
    (loading the plugins, building the engine's model: several times a lift rollout on mujoco-flex), which the
    training pays once per worker, not per simulation. None when it failed."""
    cfg, space, ctx, prior = _prepared(recording, cfg)
    prior.store.check_writable()  # a store that cannot take the task refuses before these simulations
    u = prior_unit_draws([cfg.seed, 0, 0], 2, space.names)  # the first rows of the nominal model's prior draws
    items = [JobItem(t, int(s)) for t, s in zip(space.from_unit(u), _round_seeds(cfg.seed, 0, 2))]
    res = run_jobs(replace(ctx, bank=None), items, workers=1, executor=cfg.executor,
                   executor_options=cfg.executor_options, label="one simulation, timed")[-1]
    return float(res.seconds) if res.ok and res.seconds else None


def training_plan(n_models: int, n_prior: int, n_test: int, check_null: int, seconds: float | None,
                  workers: int | None, null_rollouts: int = defaults.N_NULL, screening: int = 0,
                  refit_null: int = 0, sensor_models: int = 0) -> str:
    """What ``task train`` will spend, said before it starts: ``n_models`` models of ``n_prior`` prior and
    ``n_test`` held-out simulations each, but ``sensor_models`` of them, whose simulations are the nominal model's
    rollouts read from the bank (:func:`~softsbi.workflows.fit.jobs.prior_unit_draws`); the nominal model's
    ``check_null`` replicate recordings of
    ``null_rollouts + 1`` simulations and ``screening`` finite differences each
    (:func:`~softsbi.workflows.criticism.screening.screening_size`); each candidate model's ``refit_null`` replicates
    of ``null_rollouts + 1`` simulations (not screened); with ``seconds`` (one simulation's time,
    :func:`pilot_seconds`) the time on ``workers`` processes (None: one per CPU), the estimators' training not
    included. An upper bound: models and replicates already stored and simulations in the bank are not simulated
    again."""
    per, per_refit = null_rollouts + 1 + screening, null_rollouts + 1
    refit_null = refit_null if n_models > 1 else 0
    simulated = n_models - sensor_models
    total = simulated * (n_prior + n_test) + check_null * per + (n_models - 1) * refit_null * per_refit
    s = (f"task train plan: {simulated} model{'s' if simulated > 1 else ''} x ({n_prior} prior + {n_test} held-out "
         f"simulations)" + (f" (and {sensor_models} sensor model{'s' if sensor_models > 1 else ''}, whose "
                            f"simulations are the nominal model's)" if sensor_models else "")
         + (f" + {check_null} replicate recordings x {per} for the nominal check's calibration"
                            if check_null else "")
         + (f" + {n_models - 1} x {refit_null} x {per_refit} for the refits' checks" if refit_null else "")
         + f" = {total} simulations at most")
    if seconds is None:
        return s + " (one simulation's time unknown: it failed)"
    n = workers or os.cpu_count() or 1
    return (s + f"; one simulation took {duration_words(seconds)}, so about {duration_words(total * seconds / n)} "
                f"on {n} worker{'s' if n > 1 else ''}, plus the training (fewer when stored models or the simulation "
                f"bank hold some)")


def calibration_advice(tasks: Sequence[StoredTask]) -> str | None:
    """What to do about trained tasks whose training report says "not calibrated" (None: every reported one is
    calibrated): fits of the task use them anyway, stopping at the stored posterior after one round; training them
    on more prior simulations, or deleting them (the task's fits then run their own sequential rounds), is the
    remedy."""
    bad = [t for t in tasks if t.report is not None and not t.report.calibrated]
    if not bad:
        return None
    one = len(bad) == 1
    it, is_, its = ("it", "is", "its") if one else ("them", "are", "their")
    return (f"{len(bad)} of the {len(tasks)} models {is_} not calibrated on {its} held-out simulations "
            f"({', '.join(t.model for t in bad)}). Fits of the task use {it} anyway (a fit of a new recording stops "
            f"at the stored posterior after one round), so {its} intervals may be too narrow or too wide: train "
            f"again on more prior simulations (`softsbi task train ... --prior-sims {2 * max(t.n_prior for t in bad)}` "
            f"retrains {it}), or delete {it} (`softsbi task delete KEY`) so that fits run their own sequential "
            f"rounds.")


def _with_check_null(task: StoredTask, recording: Recording, cfg: FitConfig, space: ParamSpace, ctx: SimContext,
                     n: int, say: Callable[[str], None], screened: Sequence[str] | None = ()) -> StoredTask:
    """The task, with ``n`` replicates for check's calibration computed unless at least as many are stored, screened
    against a family holding the model's default one and ``screened`` less its own effects (``n`` 0: none;
    ``screened`` None: not screened)."""
    family = [] if screened is None else replicate_family(cfg, recording, screened)
    stored = stored_check_null(task, defaults.N_NULL, int(recording.dense.shape[1]))
    if n > 0 and (stored is None or len(stored.statistics) < n or not stored.calibrates([c.name for c in family])):
        train_check_null(task, recording, cfg, space, ctx, n, defaults.N_NULL, cfg.workers, say, family)
    return task


def replicate_family(cfg: FitConfig, recording: Recording, screened: Sequence[str] = ()) -> list[Any]:
    """The candidates a model's replicates are screened against: its default family
    (:func:`~softsbi.workflows.criticism.screening.default_candidates`) and ``screened``, less the model's own
    effects (instances)."""
    family = default_candidates(cfg.backend, recording.scenario, cfg.effects)
    have = {c.name for c in family} | set(cfg.effects)
    return family + [registry().effect(n)() for n in dict.fromkeys(screened) if n not in have]


def _state(est: Any, name: str, opts: dict[str, Any]) -> EstimatorState:
    return EstimatorState(name, dict(opts), est.state_dict())


def _held_out(ctx: SimContext, space: ParamSpace, cfg: FitConfig, n_test: int,
              stream: int = TEST_STREAM) -> tuple[np.ndarray, np.ndarray]:
    """``(U, X)``: the usable ones of a model's ``n_test`` held-out prior simulations of seed stream ``stream``."""
    u = prior_unit_draws([cfg.seed, stream, 0], n_test, space.names, sensor_parameters(cfg.backend, cfg.effects))
    return _simulate(ctx, space, u, _round_seeds(cfg.seed, stream, n_test), cfg, "held-out prior simulations")


def held_out_simulations(recording: Recording, cfg: FitConfig, n_test: int = defaults.N_TEST,
                         stream: int = TEST_STREAM) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Held-out prior simulations of a model (``cfg.effects`` the model) through the simulation bank (those
    simulated before are read): ``(names, U (n, D) unit cube, X (n, T, 1+K, 3) at the fit's frames)``, the failed
    ones left out. ``stream``: :data:`~softsbi.core.seeds.TEST_STREAM`, the training report's;
    :data:`~softsbi.core.seeds.FRESH_TEST_STREAM`, a second set no choice was made on.

    Raises:
        SoftsbiError: as :func:`train_model` before simulating; every simulation failed."""
    cfg, space, ctx, prior = _prepared(recording, cfg)
    U, X = _held_out(replace(ctx, bank=str(prior.store.path.parent)), space, cfg, n_test, stream)
    return tuple(space.names), U, X[:, slice(None) if cfg.frames is None else list(cfg.frames)]


def held_out_report(est: Any, names: Sequence[str], U: np.ndarray, X: np.ndarray, n_draws: int, seed: int,
                    n_failed: int = 0) -> TrainingReport:
    """A trained estimator measured on held-out prior simulations ``U (n, D)`` (unit cube), ``X`` (at its frames):
    expected coverage, SBC ranks, TARP and their verdict, and the contraction per parameter (module docstring,
    step 3), as a :class:`~softsbi.core.results.fitreport.TrainingReport` (without its times).

    Raises:
        PosteriorError: no posterior of a held-out simulation has mass in the prior box."""
    st = calibration_stats(est, U, X, list(names), n_draws, defaults.N_BINS, seed)
    lo, hi = np.quantile(st["draws"], 0.05, axis=1), np.quantile(st["draws"], 0.95, axis=1)  # (n, D) unit cube
    ratio = np.median((hi - lo) / 0.9, axis=0)  # the prior's central 90% spans 0.9 of the unit cube
    ver = st["ver"]
    return TrainingReport.from_json({
        "n_test": int(st["n"]), "n_test_failed": int(n_failed), "n_draws": int(n_draws),
        "parameters": list(names),
        "coverage": coverage_json(st), "sbc": rank_histograms_json(st, defaults.N_BINS),
        "tarp": st["tarp"], "verdict": ver["verdict"], "calibrated": ver["calibrated"],
        "too_narrow": ver["too_narrow"], "too_wide": ver["too_wide"], "biased": ver["biased"],
        "contraction": {n: {"width_ratio": float(r), "informed": bool(r <= INFORMED_MAX_RATIO)}
                        for n, r in zip(names, ratio)}})


def training_report(est: Any, ctx: SimContext, space: ParamSpace, cfg: FitConfig, n_test: int, n_draws: int,
                    fr: Any) -> TrainingReport:
    """The training report of a trained task: its amortised posterior on ``n_test`` held-out prior simulations
    (module docstring, step 3)."""
    t0 = time.perf_counter()
    U, X = _held_out(ctx, space, cfg, n_test)
    sim_s = time.perf_counter() - t0
    report = held_out_report(est, space.names, U, X[:, fr], n_draws, cfg.seed, n_test - len(U))
    return replace(report, simulation_seconds=sim_s)


@pools.shared_executors()
def train_task(recording: Recording, cfg: FitConfig, n_prior: int = defaults.TASK_PRIOR_SIMS,
               candidates: Sequence[str] | None = None,
               n_test: int = defaults.N_TEST, n_draws: int = defaults.N_DRAWS, retrain: bool = False,
               check_null: int = defaults.CHECK_REPLICATES,
               message: Callable[[str], None] | None = None,
               refit_null: int = defaults.REFIT_REPLICATES) -> list[StoredTask]:
    """Train a task once for the nominal model and each candidate effect (:func:`candidate_models`,
    :func:`train_model`); returns the stored tasks, nominal first. Replicate recordings calibrate the check of a
    model's fits (:mod:`~softsbi.workflows.criticism.check_null`): the nominal model's ``check_null``, screened
    against every candidate, ``diagnose``'s detection (both tests); each candidate model's ``refit_null``, not
    screened, the adequacy check of its refit by the omnibus test alone
    (:func:`~softsbi.workflows.criticism.check_null.run_check_null`).

    Raises:
        SoftsbiError: ``n_test`` between 1 and ``defaults.MIN_TEST - 1``. ResultUnwritable: a model's
            ``check-null.json`` cannot be written (a folder in its place; before any simulation).
        everything :func:`train_model`, :func:`candidate_models` and
        :func:`~softsbi.workflows.criticism.check_null.check_replicates` raise."""
    check_replicates(check_null)
    check_replicates(refit_null, "--refit-null")
    if n_test and n_test < defaults.MIN_TEST:
        raise SoftsbiError(f"--n-test must be 0 (no training report) or >= {defaults.MIN_TEST} (got {n_test}): fewer "
                           f"held-out simulations cannot judge the calibration")
    models = candidate_models(cfg, candidates)
    for i, effects in enumerate(models):  # a folder in a replicates file's place: refused before any work
        if not (check_null if i == 0 else refit_null):
            continue
        prior = _prepared(recording, replace(cfg, effects=effects))[3]
        check_result_path(prior.store.path / prior.digest / NULL_FILE)
    say = message or (lambda s: None)
    screened = [m[-1] for m in models[1:]]
    screening = screening_size(_prepared(recording, cfg)[1].dim, replicate_family(cfg, recording, screened)) \
        if check_null else 0
    sensor = [set(p.name for p in registry().effect(m[-1])().param_space()) <= sensor_parameters(cfg.backend, m)
              for m in models[1:]]
    say(training_plan(len(models), n_prior, n_test, check_null, pilot_seconds(recording, cfg), cfg.workers,
                      screening=screening, refit_null=refit_null, sensor_models=sum(sensor)))
    each = [n_prior + n_test + check_null * (defaults.N_NULL + 1 + screening)] + \
        [(0 if s else n_prior + n_test) + refit_null * (defaults.N_NULL + 1) for s in sensor]
    out = []
    for i, effects in enumerate(models, start=1):
        done = sum(each[:i - 1])
        say(f"model {i} of {len(models)}: {'+'.join(['nominal', *effects[len(cfg.effects):]])} (simulations "
            f"{done + 1}-{done + each[i - 1]} of {sum(each)} at most)")
        out.append(train_model(recording, replace(cfg, effects=effects), n_prior, n_test, n_draws, retrain,
                               check_null if i == 1 else refit_null, say, screened=screened if i == 1 else None))
        if i > 1 and n_test:
            with_off_null(out[-1], recording, replace(cfg, effects=effects), n_test, n_draws, say)
    return out


def with_off_null(task: StoredTask, recording: Recording, cfg: FitConfig, n_test: int, n_draws: int,
                  say: Callable[[str], None]) -> None:
    """Store the null of "switched on" for the candidate model ``cfg.effects`` (its last effect the candidate)
    unless the task has it: the statistic of its amortised posterior on the ``n_test`` held-out prior simulations of
    the model without the candidate (the training report's, read from the simulation bank),
    :func:`~softsbi.workflows.criticism.switched_on.train_off_null`.

    Raises:
        ResultUnwritable: the null cannot be written."""
    if stored_off_null(task.path) is not None:
        return
    effect = registry().effect(cfg.effects[-1])()
    space = _prepared(recording, cfg)[1]
    _, _, x = held_out_simulations(recording, replace(cfg, effects=list(cfg.effects[:-1])), n_test)
    null = train_off_null(task.restore(), x, unit_off_values(effect, space), n_draws, cfg.seed)
    store_off_null(task.path, null, n_draws)
    say(f"{task.model}: 'switched on' calibrated on {int(np.isfinite(null).sum())} of the model without "
        f"{effect.name}'s held-out simulations")
