"""Is the nominal model enough, and which candidate effect is missing? Detect, propose, decide.

:func:`diagnose_run` runs the three steps of :mod:`softsbi.workflows.criticism.decide` on a finished fit:

1. *detect*: ``check``'s joint test (:func:`~softsbi.workflows.criticism.screening.misspecification_verdict`: the
   omnibus and the directional test on one null of posterior-predictive rollouts, min-p combined; calibrated against
   the task's replicates on a trained task);
2. *propose*: on a task trained with its candidate models, each trained candidate's amortised posterior predictive is
   scored (:mod:`~softsbi.workflows.criticism.evidence`); the linearised screening ranks the candidate effects
   (:class:`~softsbi.workflows.criticism.screening.Screening`); the top ones of :func:`~softsbi.workflows.criticism.decide.refit_order`
   are refitted (:func:`refit_model`; :func:`~softsbi.workflows.criticism.decide.next_refit` says which);
3. *decide*: :func:`~softsbi.workflows.criticism.decide.decide` on the refits' adequacy (the same test) and summary energy scores.

One candidate family is used in every step: the refits' tests screen the same candidates less their own effects.
The result is a :class:`~softsbi.core.results.Diagnosis`, written to ``RUN/diagnosis.json``; its sentences are
rendered by :mod:`softsbi.report.text`.
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from softsbi.core.errors import PosteriorError, SimulationFailed, SoftsbiError
from softsbi.core.results import (Diagnosis, Estimate, Refit, read_result,
                                  check_result_path, write_result)
from softsbi.core.results.joint import CHANCE_EXCLUDED
from softsbi.core.types import Param
from softsbi.inference.contraction import BOUND_SLAB
from softsbi.plugins import registry
from softsbi.core.results.fitreport import FitReport
from softsbi.workflows.criticism.check import check_run, loaded, result_key, reused, stored_result
from softsbi.workflows import pools
from softsbi.workflows.criticism.decide import decide, next_refit, to_refine
from softsbi.workflows.criticism.evidence import (RACE_START, START_EPS, START_PAD, amortised_refit, amortised_scores,
                                                  recording_from_run, refit_config, refit_dir, start_box,
                                                  trained_task, trained_tasks, uninformed_candidates)
from softsbi.workflows.reporting import duration_words, fit_callbacks
from softsbi.workflows.fit.run import run_fit
from softsbi.workflows.lock import check_out_apart, run_lock
from softsbi.workflows.fit.runs import RunView
from softsbi.workflows.fit.task_store import read_once
from softsbi.workflows.criticism.screening import candidate_effects, check_resolution, is_generic
from softsbi.workflows.criticism.stats import N_NULL, PosteriorPredictive, run_features
from softsbi.workflows.criticism.switched_on import off_test, stored_off_null
from softsbi.workflows.criticism.statistics import summary_energy_score, summary_scale
from softsbi.core.defaults import REFINE_ROUNDS, REFINE_SIMS, ROUNDS, DiagnoseSettings

@pools.shared_executors()
@read_once()  # each stored task read once: the candidates' amortised posteriors, refits and checks share it
def diagnose_run(run_dir: str | Path, effects: Sequence[str] | None = None, *,
                 settings: DiagnoseSettings | None = None, progress: Callable[[str], None] | None = None,
                 pool: PosteriorPredictive | None = None, recompute: bool = False,
                 out_dir: str | Path | None = None, plots: bool = True) -> Diagnosis:
    """Is the nominal model enough, and if not, which candidate effect is missing? Writes ``diagnosis.json``.

    Args:
        run_dir: a finished fit of the nominal model.
        effects: the candidate family (default: every installed effect the backend can apply and the run lacks,
            generic force terms included).
        settings: the tests' level, the score margin, the refits and the null
            (:class:`~softsbi.core.defaults.DiagnoseSettings`; None: the defaults). A refit budget of None is the
            nominal fit's (its own values are stored under the same key as None; a refit at a smaller budget has a
            wider posterior predictive, which ``check`` rejects less often: measured on a toy magnet, a flexible
            candidate refitted at half the budget passed where at the full budget it did not).
        progress: told each step (``callable(str)``), and what was written or reused.
        pool: posterior-predictive rollouts of this run already simulated (``check``'s, same ``seed``).
        recompute: diagnose again even when ``diagnosis.json`` holds the result for the same fit and settings.
        out_dir: the folder of ``diagnosis.json``, the nominal fit's check (``check.json``, ``check.png``) and the
            refits (default: the run directory), so that two diagnoses of one run can be kept; the run directory is
            then not written (its own ``check.json`` is reused when it holds the same settings).
        plots: draw the figures of the check and of each refit (``check.png``, the fit figures); the result does
            not depend on it, and a stored result is reused either way.

    Returns:
        the :class:`~softsbi.core.results.Diagnosis`.

    Raises:
        SoftsbiError: no candidates; a null cap that cannot resolve ``alpha``; the nominal fit has too few
            successful rollouts.
        RunLocked: another process writes ``out_dir`` (e.g. a second diagnose of the run), before any work.
        RunDirError: ``out_dir`` is or lies inside another run's directory, or holds another run's diagnosis
            (:func:`~softsbi.workflows.lock.check_out_apart`), before any work.
        ResultUnwritable, RunDirError: ``diagnosis.json`` or ``out_dir`` cannot be written (a folder in the
            file's place: before any work; a full disk: when the result is written, the refits kept).
    """
    t0 = time.perf_counter()
    s = settings or DiagnoseSettings()
    alpha, k_se, confirm, n_null, max_null, workers, seed = (s.alpha, s.k_se, s.confirm, s.n_null, s.max_null,
                                                             s.workers, s.seed)
    check_resolution(alpha, max_null)
    if out_dir is not None:
        check_out_apart(out_dir, "diagnose", run=run_dir)
    run = loaded(run_dir, pool, seed)  # loaded once: the pool, check and the refits share it
    refit_rounds, refit_sims = refit_budget(run, s)
    say = progress or (lambda _: None)
    cands = candidate_effects(run, effects, say)
    if not cands:
        raise SoftsbiError("no candidate effects: install effect plugins or name them with --effect")
    family = tuple(c.name for c in cands)
    trained = trained_tasks(run, [c.name for c in cands if not is_generic(c)])
    # on a trained task a candidate's refit is its amortised posterior unless sequential rounds are asked for
    key = result_key(run, family=sorted(family), trained=sorted(t[0].digest for t in trained.values()), alpha=alpha,
                     k_se=k_se, confirm=confirm, refit_rounds=refit_rounds, refit_sims=refit_sims, n_null=n_null,
                     max_null=max_null, seed=seed, amortised_refits=sorted(trained) if refit_rounds is None else [],
                     race_start=RACE_START, refine=[s.refine, REFINE_ROUNDS, REFINE_SIMS],
                     pair_start=[START_EPS, START_PAD])
    out = run.path if out_dir is None else Path(out_dir)
    json_path = check_result_path(out / "diagnosis.json")
    stored = None if recompute else stored_result(json_path, Diagnosis, key, say)
    if stored is not None:
        say(reused(json_path))
        return stored
    busy = (f"wait for it to finish (a diagnose with the same settings then reuses its result), or keep a second "
            f"diagnosis apart with `softsbi diagnose {run.path} --out OTHER_FOLDER`")
    with run_lock(out, command="diagnose", busy=busy):
        say(diagnosis_plan(run.report, len(family), confirm, refit_rounds, refit_sims, n_null,
                           0 if refit_rounds is not None else len(trained), s.refine))
        say(f"detect: posterior predictive check of {run.path} against {len(family)} candidates")
        pool = pool or PosteriorPredictive(run, workers, seed)
        chk = check_run(
            run,
            pool=pool,
            effects=family,
            recompute=recompute,
            message=say,
            plot=plots,
            out_dir=None if out_dir is None else out,
            settings=s.check(),
        )
        # the score every model is compared on: the energy score of check's summaries in the nominal's scale
        f_nom = pool.ensure(n_null).features[:n_null]  # the null's first stage (simulated here if check was stored)
        scale = summary_scale(f_nom)
        nominal = summary_energy_score(run_features(run, run.dense), f_nom, scale)
        ranking, n_amortised = chk.ranking, 0
        amortised: dict[str, PosteriorPredictive] = {}  # each trained candidate's refit run's rollouts
        if chk.test.misspecified and confirm > 0 and trained:  # each trained candidate's amortised refit's score
            say(f"propose: the amortised posterior predictive of the {len(trained)} candidates the task trained")
            amortised = amortised_pools(run, trained, out, s, say)
            scores, n_amortised = amortised_scores(run, amortised, scale, n_null, nominal, confirm, k_se)
            ranking = tuple(replace(c, amortised=scores.get(c.effect)) for c in ranking)
        refits: list[Refit] = []
        refined = False  # the singles' refinements come before the pair (decide.to_refine)
        while True:
            nxt = next_refit(chk.test, ranking, nominal, refits, confirm, k_se)
            if not refined and (nxt is None or len(nxt) > 1):
                refined = True
                refits = refine_refits(run, family, refits, chk.test, nominal, s, scale, out, plots, say, trained)
                continue
            if nxt is None:
                break
            singles = [r for r in refits if len(r.effects) == 1 and r.effects[0] in nxt] if len(nxt) > 1 else []
            say(f"refit {len(refits) + 1}: the nominal model with {' + '.join(nxt)}"
                + (f", its first round in the box of {' and '.join(r.effects[0] for r in singles)}'s posterior"
                   f"{'s' if len(singles) > 1 else ''}" if singles else ""))
            refits.append(refit_model(run, nxt, family, settings=s, scale=scale, rounds=refit_rounds,
                                      sims_per_round=refit_sims, out_root=out, plots=plots,
                                      pool=amortised.get(nxt[0]) if len(nxt) == 1 else None,
                                      start=start_box(singles) if singles else None))
        decision = decide(chk.test, nominal, refits, k_se)
        generic = next((c for c in chk.ranking if c.generic and c.screened), None) if chk.test.misspecified else None
        # 0 from check when its result was stored
        sims = pool.requested + sum(len(v[2]) for v in pool.sensitivities.values()) + n_amortised
        d = Diagnosis(
            run=str(run.path),
            candidates=family,
            alpha=alpha,
            k_se=k_se,
            test=chk.test,
            ranking=ranking,
            nominal=nominal,
            refits=tuple(refits),
            decision=decision,
            residual=chk.residual,
            generic=generic,
            simulations=sims,
            key=key,
            seconds=time.perf_counter() - t0,
            chamfer_m=chk.chamfer_mean_m,
            chamfer_n=chk.n_rollouts,
            confirm=confirm,
            uninformed=uninformed_candidates(trained),
        )
        write_result(json_path, d)
    say(f"wrote {json_path}")
    return d


def refine_refits(run: RunView, family: Sequence[str], refits: list[Refit], test: Any, nominal: Any,
                  s: DiagnoseSettings, scale: np.ndarray, out: Path, plots: bool,
                  say: Callable[[str], None], trained: Mapping[str, Any]) -> list[Refit]:
    """``refits`` with the first ``s.refine`` of :func:`~softsbi.workflows.criticism.decide.to_refine`'s replaced by
    their refinements: each the same model fitted again after its amortised posterior (round 1, read from its task)
    in :data:`~softsbi.core.defaults.REFINE_ROUNDS` sequential rounds of :data:`~softsbi.core.defaults.REFINE_SIMS`
    truncated-proposal simulations (at most the task's prior simulations, so that round 1 is the stored task;
    ``refit-<effect>-sequential``), checked and scored as any refit, with
    ``refined_from`` the amortised refit. A refinement that cannot be fitted (its posterior has no mass in the prior
    box, every simulation failed) is told to ``say`` and the amortised refit is kept: it explains nothing more.
    ``trained``: the candidates' trained tasks (:func:`~softsbi.workflows.criticism.evidence.trained_tasks`)."""
    out_refits = list(refits)
    for effects in to_refine(test, nominal, refits, s.k_se)[:s.refine]:
        i = next(k for k, r in enumerate(out_refits) if r.effects == effects)
        say(f"refine: {' + '.join(effects)}'s amortised refit is adequate and improves on the nominal fit, but the "
            f"data may leave it off; fitting it again in {REFINE_ROUNDS} sequential rounds of {REFINE_SIMS} after its "
            f"amortised posterior")
        task = trained.get(effects[0])  # an amortised refit's: always there
        sims = REFINE_SIMS if task is None else min(REFINE_SIMS, task[0].n_prior)  # round 1: the stored task
        try:
            new = refit_model(run, effects, family, settings=s, scale=scale, rounds=1 + REFINE_ROUNDS,
                              sims_per_round=sims, out_root=out, plots=plots)
        except (PosteriorError, SimulationFailed) as exc:  # an environment fault or a full disk still ends it
            say(f"refine: {' + '.join(effects)} could not be refined ({exc}); its amortised refit is kept")
            continue
        out_refits[i] = replace(new, refined_from=out_refits[i])
    return out_refits


def refit_budget(run: RunView, s: DiagnoseSettings) -> tuple[int | None, int | None]:
    """The refits' rounds and simulations per round that ``s`` asks of ``run``'s diagnosis, None for "the run's own"
    (one stored key for both spellings of the default). An asked number of rounds is "the run's own" only when the
    run did not stop at a stored task: one that did ran one round whatever its settings said, and "its own" then
    means each refit's own task (:func:`~softsbi.workflows.criticism.evidence.refit_config`: the default rounds for
    an untrained candidate), so an asked budget is kept as asked and never depends on which recording filled the
    task first."""
    base, rep = run.config, run.report
    at_task = bool(rep.task)  # "the run's own" then means each refit's own task
    rounds = None if s.refit_rounds is not None and s.refit_rounds == base.rounds and not at_task else s.refit_rounds
    sims = None if s.refit_sims == base.sims_per_round else s.refit_sims
    return rounds, sims


def diagnosis_plan(report: FitReport, candidates: int, confirm: int, refit_rounds: int | None = None,
                   refit_sims: int | None = None, n_null: int = N_NULL, amortised: int = 0, refine: int = 0) -> str:
    """What a diagnosis of the fit ``report`` describes will spend, said before it starts: the check's ``n_null``
    posterior rollouts and the screening of ``candidates``, then, when the check rejects, up to ``confirm`` single
    refits and one pair (:func:`~softsbi.workflows.criticism.decide.next_refit`), each a fit at the refit budget
    (``refit_rounds`` x ``refit_sims``, None: the nominal fit's) and its check; the time at the nominal fit's pace
    (its wall time over its simulations, training included). ``amortised`` candidates have a trained task: their
    refits are their amortised posteriors (:func:`~softsbi.workflows.criticism.evidence.amortised_refit`), whose
    ``n_null`` rollouts are spent on scoring them all, and which simulate no rounds; up to ``refine`` of them may be
    refined (:func:`refine_refits`). Upper bounds: simulations read from the bank cost less; a null extended to
    resolve the level, more."""
    rounds, sims = report.rounds or 1, report.sims_per_round or 0
    n_eval = max((report.simulations or 0) - rounds * sims, 0)
    # "the run's own" rounds of a run that stopped at its stored task are an untrained refit's default ones
    at_task = bool(report.task)
    r_rounds, r_sims = refit_rounds or (ROUNDS if at_task else rounds), refit_sims or sims
    per_refit = r_rounds * r_sims + n_eval + n_null
    refits = confirm + (1 if confirm >= 2 else 0)
    total = n_null + refits * per_refit
    s = f"diagnose plan: the check's {n_null} posterior rollouts and the screening of {candidates} candidates"
    if refits:
        top = f"the top {confirm} candidates" if confirm > 1 else "the top candidate"
        first = ""
        if amortised:  # the trained candidates' refits are their amortised posteriors, scored first
            total += amortised * n_null
            first = (f"the amortised posteriors of the {amortised} trained candidate{'s' if amortised > 1 else ''} "
                     f"({min(RACE_START, n_null)} to {n_null} rollouts each, as their decision needs; a trained "
                     f"candidate's refit simulates no round) and ")
        s += (f", then, if the check rejects, {first}up to {refits} refit{'s' if refits > 1 else ''} ({top}"
              f"{', then a pair' if refits > confirm else ''}) of about {per_refit} simulations each ({r_rounds} "
              f"round{'s' if r_rounds > 1 else ''} x {r_sims} simulations, then its check)"
              f"{' when no task trained the candidate' if amortised else ''}")
        if amortised and refine:  # each refinement: its sequential rounds, then its check's rollouts
            total += min(refine, confirm) * (REFINE_ROUNDS * REFINE_SIMS + n_null)
            s += (f", and up to {min(refine, confirm)} refinement{'s' if min(refine, confirm) > 1 else ''} of an "
                  f"amortised refit whose effect may be off ({REFINE_ROUNDS} rounds x {REFINE_SIMS} simulations, then "
                  f"its check)")
        s += f": {total} simulations at most"
    if report.wall_time_s and report.simulations:
        pace = report.wall_time_s / report.simulations
        s += (f"; about {duration_words(total * pace)} at the nominal fit's pace ({report.simulations} simulations "
              f"in {duration_words(report.wall_time_s)})")
    return s + (f" (--confirm {confirm} sets the number of refits)" if refits else "")


@pools.shared_executors()
@read_once()
def refit_model(run: RunView, effects: Sequence[str], family: Sequence[str], *,
                settings: DiagnoseSettings | None = None, scale: np.ndarray | None = None, rounds: int | None = None,
                sims_per_round: int | None = None, out_root: str | Path | None = None, plots: bool = True,
                pool: PosteriorPredictive | None = None, start: Mapping[str, Sequence[float]] | None = None) -> Refit:
    """Fit ``run``'s measurement again with ``effects`` added, then check the refit.

    On a task trained with the refit's model, when the nominal fit stopped at its trained task and no ``rounds``
    are asked for, the refit is the model's amortised posterior
    (:func:`~softsbi.workflows.criticism.evidence.amortised_refit`: its stored estimator conditioned on the
    recording, no rounds simulated) in ``RUN/refit-<a>+<b>``; its check is calibrated against the model's own
    replicates when ``task train`` stored them (by its omnibus test alone when they were not screened, a candidate
    model's: :func:`~softsbi.workflows.criticism.check_null.run_check_null`), else uncalibrated.
    Otherwise the refit runs sequential rounds at :func:`~softsbi.workflows.criticism.evidence.refit_config`'s
    settings (by default the nominal fit's budget, so that an added effect is fitted as well as the model it
    extends), in ``RUN/refit-<a>+<b>`` (``refit-<a>+<b>-sequential`` for a model with a trained task:
    :func:`~softsbi.workflows.criticism.evidence.refit_dir`), and resumes from there; ``out_root`` replaces ``RUN``.

    Either is checked by :func:`~softsbi.workflows.criticism.check.check_run` (so ``check.json`` is there for
    ``compare``) with ``settings.check()`` (None: the defaults) over ``family`` less ``effects``; its score is the
    energy score of its first ``settings.n_null`` posterior-predictive rollouts' summaries in ``scale`` (the nominal
    fit's, :func:`~softsbi.workflows.criticism.statistics.summary_energy_score`; no score without ``scale``).
    ``pool``: the refit run's rollouts already simulated (the amortised score's; used when it is this refit's run).
    ``start``: a sequential refit's first-round box (a pair's: :func:`~softsbi.workflows.criticism.evidence.start_box`
    of its singles; None: the prior). ``plots``: draw the refit's fit figures and ``check.png``.

    Raises:
        everything :func:`~softsbi.workflows.fit.run.run_fit` raises (e.g. a stored refit with other settings).
    """
    effects = tuple(effects)
    s = settings or DiagnoseSettings()
    n_null, workers = s.n_null, s.workers
    root = Path(out_root or run.path)
    label = f"refit with {' + '.join(effects)}"
    trained = trained_task(run, effects, sims_per_round)
    if trained is not None and rounds is None:  # the trained model's amortised posterior: no rounds
        out = amortised_refit(run, effects, root, workers, plots, fit_callbacks(label))
        cfg = trained[1]
    else:
        cfg = refit_config(run, effects, rounds, sims_per_round, workers, start)
        # apart from the amortised refit whenever the model has a trained task at the run's own budget
        out = refit_dir(root, effects, sequential_of_trained=trained is not None or (
            sims_per_round is not None and trained_task(run, effects) is not None))
        run_fit(out, recording_from_run(run), cfg, callbacks=fit_callbacks(label), make_plots=plots)
    if pool is None or Path(pool.run.path).resolve() != out.resolve():
        pool = PosteriorPredictive(out, workers, s.seed)  # the refit, loaded once: its check and score share it
    chk = check_run(pool.run, pool=pool, effects=[e for e in family if e not in effects], plot=plots,
                    settings=s.check())
    f = pool.ensure(n_null).features[:n_null]
    score = (summary_energy_score(run_features(pool.run, pool.run.dense), f, scale)
             if scale is not None and len(f) >= 3 else None)
    report = pool.run.report
    amortised = trained is not None and rounds is None
    null = stored_off_null(trained[0].path) if amortised and len(effects) == 1 else None
    tested = None if null is None else off_test(report.contraction, registry().effect(effects[0])(), trained[2], null)
    # its Chamfer from its check, over as many rollouts as the nominal's (Diagnosis.chamfer_m), not the fit's n_eval
    return Refit(effects=effects, run=str(out), test=chk.test, score=score, chamfer_m=chk.chamfer_mean_m,
                 estimates=estimates(report, effects), ranking=chk.ranking, rounds=int(report.rounds),
                 sims_per_round=0 if amortised else cfg.sims_per_round, chamfer_n=chk.n_rollouts,
                 amortised=amortised, off_test=tested)


def amortised_pools(run: RunView, trained: Mapping[str, Any], root: Path, settings: DiagnoseSettings,
                    say: Callable[[str], None]) -> dict[str, PosteriorPredictive]:
    """Each trained candidate's amortised posterior stored as its refit run under ``root``
    (:func:`~softsbi.workflows.criticism.evidence.amortised_refit`, figures left to its refit), with its
    posterior-predictive rollouts (not yet simulated beyond the fit's own), by effect. A candidate whose amortised
    posterior puts no mass in the prior box is left out (told to ``say``): its refit would fail."""
    out: dict[str, PosteriorPredictive] = {}
    for effect in trained:
        try:
            path = amortised_refit(run, (effect,), root, settings.workers, False,
                                   fit_callbacks(f"{effect}: amortised posterior"))
        except PosteriorError as exc:
            say(f"{effect}: its amortised posterior is left out ({exc})")
            continue
        out[effect] = PosteriorPredictive(path, settings.workers, settings.seed)
    return out


def estimates(report: FitReport, effects: Sequence[str]) -> tuple[Estimate, ...]:
    """A fit's posterior of the parameters of ``effects`` (from its ``report.json``): mean, 90% interval, width
    over the prior's and the prior bound it presses, with the prior to try instead (None where the report lacks
    them: an older report)."""
    out = []
    for e in effects:
        effect = registry().effect(e)()
        off = effect.nominal()
        for p in (p for p in effect.param_space() if p.name in report.posterior_mean):
            b = report.bound_pressure(p.name)
            q05, q95 = report.interval(p.name)
            off_value, slab = off.get(p.name), report.slab_mass(p.name)
            out.append(
                Estimate(
                    name=p.name,
                    unit=p.unit,
                    mean=float(report.posterior_mean[p.name]),
                    q05=q05,
                    q95=q95,
                    width_ratio=report.width_ratio(p.name),
                    pressed=None if b is None else b.side,
                    suggested_bounds=None if b is None or b.suggested_bounds is None else tuple(b.suggested_bounds),
                    effect=e,
                    may_be_off=may_be_off(p, off_value, q05, q95, slab),
                    off_ratio=off_ratio(p, off_value, slab),
                )
            )
    return tuple(out)


def may_be_off(p: Param, off: float | None, q05: float | None, q95: float | None,
               slab_mass: tuple[float, float] | None) -> bool | None:
    """Whether parameter ``p``'s posterior may sit at ``off``, the value that switches its effect off: the data do
    not exclude it at the level :data:`~softsbi.core.results.joint.CHANCE_EXCLUDED`.

    - ``off`` inside the prior: its 90% interval ``[q05, q95]`` contains it (a calibrated interval excludes the
      true off value with probability 0.10).
    - ``off`` at a prior bound, which no interval of a continuous posterior reaches (so an interval cannot decide,
      and a posterior the data left flat would count as switched on): the Savage-Dickey density ratio, the Bayes
      factor of "off" against the effect's prior (Dickey 1971; Wagenmakers et al. 2010), estimated as the
      posterior's mass in the slab next to that bound (``slab_mass``, :func:`~softsbi.inference.contraction.
      contraction`) over the prior's, :data:`~softsbi.inference.contraction.BOUND_SLAB` (a box prior is uniform
      in the parameter's own scale). The data exclude ``off`` when the ratio is at most ``CHANCE_EXCLUDED``:
      when the effect is off, a Bayes factor against "off" reaches ``1 / c`` with probability at most ``c``
      (Markov's inequality: its mean is 1), so the chance rate is at most the interval's 0.10.

    None when the off value or what decides it (the interval; the slab mass, absent from an older report) is
    unknown.
    """
    if off is None or q05 is None or q95 is None:
        return None
    if off <= p.low or off >= p.high:
        ratio = off_ratio(p, off, slab_mass)
        return None if ratio is None else ratio > CHANCE_EXCLUDED
    return q05 <= off <= q95


def off_ratio(p: Param, off: float | None, slab_mass: tuple[float, float] | None) -> float | None:
    """The Savage-Dickey density ratio at an off value ``off`` at a prior bound of ``p`` (:func:`may_be_off`): the
    posterior's mass in the slab next to that bound (``slab_mass``: lower, upper) over the prior's,
    :data:`~softsbi.inference.contraction.BOUND_SLAB`. 1 for a posterior the data left flat, 0 for one that
    excludes the bound. None for an off value inside the prior or unknown, or without ``slab_mass``."""
    if off is None or slab_mass is None or p.low < off < p.high:
        return None
    return float(slab_mass[0 if off <= p.low else 1]) / BOUND_SLAB


def load_diagnosis(path: str | Path) -> Diagnosis:
    """Read ``diagnosis.json`` (a run directory or the file).

    Raises:
        SoftsbiError: no such file; ResultDamaged: one that cannot be read, is not a diagnosis or was written before
            typed results (no ``schema``): one line naming it and the command that writes it again.
    """
    path = Path(path)
    path = path / "diagnosis.json" if path.is_dir() and not path.name == "diagnosis.json" else path
    return read_result(path, Diagnosis, "diagnosis", "a diagnosis", f"`softsbi diagnose {path.parent}`")
