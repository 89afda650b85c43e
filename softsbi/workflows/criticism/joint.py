"""A task's diagnosis across its recordings: one verdict for a set of fits of one task (``softsbi diagnose RUN RUN ...
--out DIR``).

A physical effect of the rig is present in every recording of it; a recording's own diagnosis cannot tell it from
that recording's noise. :func:`diagnose_runs` diagnoses each recording (:func:`~softsbi.workflows.criticism.diagnose.diagnose_run`,
its stored result reused), refits the set's candidates on every recording where its own diagnosis did not
(:func:`~softsbi.workflows.criticism.diagnose.refit_model`, stored in the run's own ``refit-<effect>`` folder, where
``softsbi diagnose RUN`` would put it), and decides for the set
(:mod:`~softsbi.workflows.criticism.joint_decide`). The result is a :class:`~softsbi.core.results.joint.JointDiagnosis`,
written to ``DIR/joint-diagnosis.json``; its sentences are rendered by :mod:`softsbi.report.joint_text`.
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from softsbi.core.errors import SoftsbiError
from softsbi.core.results.joint import JointDiagnosis
from softsbi.core.results import Diagnosis, Estimate, Refit, check_result_path, read_result, write_result
from softsbi.core.store import RunStore
from softsbi.workflows import pools
from softsbi.workflows.criticism.check import loaded, reused, stored_result
from softsbi.workflows.criticism.diagnose import diagnose_run, refit_budget, refit_model
from softsbi.workflows.criticism.joint_decide import (check_recordings, decide_joint, joint_candidate, nominal_test,
                                                      ranked, rig_candidate, set_candidates)
from softsbi.workflows.criticism.screening import candidate_effects, check_resolution
from softsbi.workflows.criticism.stats import PosteriorPredictive
from softsbi.workflows.criticism.statistics import summary_scale
from softsbi.core.defaults import DiagnoseSettings
from softsbi.workflows.fit.task_store import read_once
from softsbi.core.types import ParamSpace
from softsbi.workflows.fit.config import FitConfig, RunRecord
from softsbi.workflows.fit.runs import final_posterior
from softsbi.workflows.lock import check_out_apart, check_out_dir, run_lock

#: the file a task's diagnosis is written to, in ``--out``
JOINT_FILE = "joint-diagnosis.json"
#: what makes fits one task: the same scenario, simulator, model (its effects) and observer
TASK_KEYS = ("scenario", "backend", "effects", "observer")


@pools.shared_executors()
@read_once()  # each stored task read once over the recordings' diagnoses and refits
def diagnose_runs(run_dirs: Sequence[str | Path], effects: Sequence[str] | None = None, *,
                  settings: DiagnoseSettings | None = None, progress: Callable[[str], None] | None = None,
                  out_dir: str | Path | None, recompute: bool = False, plots: bool = True,
                  candidates: Sequence[str] | None = None) -> JointDiagnosis:
    """One diagnosis for a task across its recordings: is an effect missing from every recording, and which?

    Each recording keeps its own diagnosis (its verdict, its cloth parameters and its refits: ``diagnose_run`` with
    the same ``effects`` and ``settings``, written to and reused from its run directory, as ``softsbi diagnose RUN``
    does). The candidates compared on the set are the single effects the recordings' own diagnoses refitted, the
    ones refitted on most recordings first (ties: by the screening's share of the residual summed over the
    recordings), the first ``settings.confirm`` of them
    (:func:`~softsbi.workflows.criticism.joint_decide.set_candidates`); each is refitted on every recording whose own
    diagnosis did not (in ``RUN/refit-<effect>``, at the refit budget of the settings, checked and scored in that
    recording's nominal scale), so that its scores can be summed. The decision
    (:func:`~softsbi.workflows.criticism.joint_decide.decide_joint`) names a candidate for the task when its summed
    summary energy score falls below the nominal model's by more than ``k_se`` standard errors paired over
    recordings (``sd(d_r) sqrt(R)``), it is adequate on the set (Fisher's method over its refits' check p-values does
    not reject at ``alpha``; each p-value is a Monte-Carlo one no lower than ``1/(n+1)`` resolution, so the combined
    test is conservative), and its effect is switched on (a one-sided binomial test at ``alpha`` of the recordings
    whose refit's 90% interval excludes its off value, against a chance rate of 0.10 per parameter). The set's
    detection is Fisher's method over the nominal fits' check p-values at ``alpha``.

    Args:
        run_dirs: finished fits of the nominal model, one per recording of one task (same scenario, simulator,
            effects and observer), at least three.
        effects: the candidate family of every recording (default: every installed effect the backend can apply and
            the runs lack).
        settings: as :func:`~softsbi.workflows.criticism.diagnose.diagnose_run`'s, for every recording and the set.
        progress: told each step (``callable(str)``), and what was written or reused.
        out_dir: the folder of ``joint-diagnosis.json`` (required; not inside a run directory).
        recompute: compute every recording's diagnosis and the set's again.
        plots: draw each check's and each refit's figures.
        candidates: the candidates to refit on every recording and weigh for the task, instead of those the
            recordings' own diagnoses refitted (e.g. the hypotheses a user holds about the rig); each must be in the
            family.

    Returns:
        the :class:`~softsbi.core.results.joint.JointDiagnosis`.

    Raises:
        SoftsbiError: before any work, in one line: no ``out_dir``; fewer than three runs; a run given twice; runs
            that are not fits of one task; a run that has not finished; a null cap that cannot resolve ``alpha``.
        RunDirError: ``out_dir`` cannot be written or lies inside a run directory (before any work).
        RunLocked: another process writes ``out_dir`` or one of the runs.
        Everything :func:`~softsbi.workflows.criticism.diagnose.diagnose_run` and
        :func:`~softsbi.workflows.criticism.diagnose.refit_model` raise.
    """
    t0 = time.perf_counter()
    s = settings or DiagnoseSettings()
    if out_dir is None:
        raise SoftsbiError("a diagnosis across several runs needs --out DIR, the folder of its joint-diagnosis.json "
                           "(each run keeps its own diagnosis in its folder)")
    runs = [Path(r) for r in run_dirs]
    scenarios = check_one_task(runs)
    rig = len(set(scenarios)) > 1
    check_recordings(len(runs), rig)
    check_resolution(s.alpha, s.max_null)
    if candidates is not None:
        check_candidates(runs[0], effects, candidates)
    out = check_out_apart(check_out_dir(out_dir), "diagnose")
    json_path = check_result_path(out / JOINT_FILE)
    say = progress or (lambda _: None)
    busy = "wait for it to finish (the same command then reuses its result), or write this one to another --out"
    with run_lock(out, command="diagnose", busy=busy):
        say(f"diagnose {len(runs)} recordings of "
            + (f"one rig's {len(set(scenarios))} motions ({', '.join(dict.fromkeys(scenarios))})" if rig else
               "one task")
            + ": each recording's own diagnosis, then the set's candidates refitted on every recording")
        diagnoses = []
        for i, run in enumerate(runs):
            say(f"recording {i + 1}/{len(runs)}: {run}")
            diagnoses.append(diagnose_run(run, effects, settings=s, progress=say, recompute=recompute, plots=plots))
        names = set_candidates(diagnoses, s.confirm) if candidates is None else tuple(dict.fromkeys(candidates))
        key: dict[str, Any] = {"runs": [str(r.resolve()) for r in runs], "diagnoses": [dict(d.key) for d in diagnoses],
                               "candidates": list(names), "alpha": s.alpha, "k_se": s.k_se, "confirm": s.confirm}
        stored = None if recompute else stored_result(json_path, JointDiagnosis, key, say)
        if stored is not None:
            say(reused(json_path))
            return stored
        test = nominal_test(diagnoses, s.alpha)
        if not test.rejects and names:  # the verdict is known before any refit: spend nothing on them
            say(f"the recordings' combined check does not reject (Fisher's method, p = {test.p_value:.2g} > "
                f"{s.alpha:g}): nothing is missing for the task, so {', '.join(names)} "
                f"{'is' if len(names) == 1 else 'are'} not refitted")
            names = ()
        refits, sims = set_refits(runs, diagnoses, names, s, say, plots)
        if rig:  # each recording's evidence with its own standard errors; the effect's posterior combined
            rows = [rig_candidate(e, diagnoses, refits[e], s.alpha, s.k_se) for e in names]
            rows = [replace(c, combined=combined_estimates(c)) for c in rows]
        else:
            rows = [joint_candidate(e, diagnoses, refits[e], s.alpha) for e in names]
        candidates = ranked(rows)
        j = JointDiagnosis(runs=tuple(str(r) for r in runs), recordings=tuple(diagnoses), candidates=candidates,
                           test=test, decision=decide_joint(test, candidates, s.k_se, rig), alpha=s.alpha,
                           k_se=s.k_se, confirm=s.confirm, simulations=sims + sum(d.simulations for d in diagnoses),
                           key=key, seconds=time.perf_counter() - t0, scenarios=tuple(scenarios))
        write_result(json_path, j)
    say(f"wrote {json_path}")
    return j


def set_refits(runs: Sequence[Path], diagnoses: Sequence[Diagnosis], names: Sequence[str], s: DiagnoseSettings,
               say: Callable[[str], None], plots: bool) -> tuple[dict[str, list[Refit]], int]:
    """Each candidate of ``names`` refitted on every recording: the recording's own refit when its diagnosis made
    one, else :func:`~softsbi.workflows.criticism.diagnose.refit_model` on its run (in ``RUN/refit-<effect>``, under
    the run's lock, scored in the scale of its nominal fit's first ``s.n_null`` posterior-predictive rollouts, the
    scale its diagnosis scored in). Returns the refits by effect (in the runs' order) and the posterior-predictive
    simulations requested for the scales."""
    out: dict[str, list[Refit]] = {e: [] for e in names}
    sims = 0
    for i, (path, d) in enumerate(zip(runs, diagnoses)):
        missing = [e for e in names if d.refit((e,)) is None]
        made: dict[str, Refit] = {}
        if missing:
            run = loaded(path, None, s.seed)
            rounds, sims_per_round = refit_budget(run, s)
            pool = PosteriorPredictive(run, s.workers, s.seed)
            scale = summary_scale(pool.ensure(s.n_null).features[:s.n_null])
            sims += pool.requested
            with run_lock(run.path, command="diagnose",
                          busy="wait for its diagnosis to finish, then run the same command again"):
                for e in missing:
                    say(f"recording {i + 1}/{len(runs)}: refit with {e} (a candidate of the set)")
                    made[e] = refit_model(run, (e,), d.candidates, settings=s, scale=scale, rounds=rounds,
                                          sims_per_round=sims_per_round, out_root=run.path, plots=plots)
        for e in names:
            out[e].append(d.refit((e,)) or made[e])
    return out, sims


def check_candidates(run: Path, effects: Sequence[str] | None, candidates: Sequence[str]) -> None:
    """Refuse, in one line and before any work, set candidates outside the family of ``run`` (a fit of the task)
    or none at all.

    Raises:
        SoftsbiError: naming the candidate and the family.
    """
    if isinstance(candidates, str):
        raise SoftsbiError(f"candidates must be a list of effect names, e.g. [{candidates!r}]")
    family = [c.name for c in candidate_effects(loaded(run), effects)]
    if not candidates:
        raise SoftsbiError(f"no candidates: name at least one of the diagnosis's family {family}")
    bad = [c for c in candidates if c not in family]
    if bad:
        raise SoftsbiError(f"candidate {bad[0]!r} is not in the diagnosis's family {family}: name candidates the "
                           f"model lacks and the backend can apply (or widen --effect)")


def task_of(config: dict[str, Any]) -> dict[str, Any]:
    """What a run's stored settings (``RunStore.config``) say of its task (:data:`TASK_KEYS`): the scenario's name,
    the simulator, the model's effects (sorted) and the observer."""
    cfg, record = FitConfig.from_run_config(config), RunRecord.from_run_config(config)
    return {"scenario": record.scenario["name"], "backend": cfg.backend, "effects": sorted(cfg.effects),
            "observer": cfg.observer}


def check_one_task(runs: Sequence[Path]) -> list[str]:
    """Refuse, before any work and in one line, runs that are not finished fits of one task or of one rig: a run
    given twice, a folder that is no run or whose fit has not finished, or runs whose configs name another simulator,
    model or observer (:func:`task_of`; the scenario may differ: a rig's several motions). Returns each run's
    scenario.

    Raises:
        SoftsbiError: naming the run and what differs.
    """
    seen: dict[Path, Path] = {}
    for r in runs:
        if r.resolve() in seen:
            raise SoftsbiError(f"run '{r}' is given twice (as '{seen[r.resolve()]}'): each recording counts once in a "
                               f"task's diagnosis")
        seen[r.resolve()] = r
    tasks = []
    for r in runs:
        config = RunStore.open(r / "run.zarr", mode="r").config
        if not (r / "report.json").exists():
            raise SoftsbiError(f"'{r}' has no report.json: the fit has not finished; resume it with the same "
                               f"`softsbi fit ... --out {r}` command first")
        tasks.append(task_of(config))
    for r, t in zip(runs[1:], tasks[1:]):
        diff = [k for k in TASK_KEYS if k != "scenario" and t[k] != tasks[0][k]]
        if diff:
            k = diff[0]
            raise SoftsbiError(f"the runs are not fits of one rig: '{runs[0]}' has {k} {tasks[0][k]!r}, '{r}' has "
                               f"{t[k]!r}; a diagnosis across recordings compares one model of one object and rig, so "
                               f"diagnose runs of the same simulator, model and observer together (their motions, "
                               f"the scenarios, may differ)")
    return [t["scenario"] for t in tasks]


#: posterior draws per recording and bins of the unit interval behind a rig's combined estimates
COMBINED_DRAWS, COMBINED_BINS = 4000, 64


def combined_estimates(c: Any) -> tuple[Estimate, ...]:
    """Each effect parameter of a rig's candidate ``c`` (:class:`~softsbi.core.results.joint.JointCandidate`)
    combined over the recordings that inform it (:attr:`~softsbi.core.results.joint.JointCandidate.informed_by`):
    the normalised product of their refits' marginal posteriors, each a histogram of :data:`COMBINED_DRAWS` draws on
    :data:`COMBINED_BINS` bins of the parameter's unit interval (half a draw added to every bin, so that no recording
    rules a region out on a few draws), with its mean and central 90% interval in physical units.

    Assumptions, stated with the result: the recordings are independent given the parameters; the effect's parameters
    are one value for the rig (the same object, rig and effect in every motion); the prior is uniform in the unit
    cube (each refit's); and the product of the marginals stands for the marginal of the product, exact when the
    parameter is a posteriori independent of the others in each recording. A parameter is combined only over the
    refits that infer it; a refit whose posterior cannot be read is left out."""
    names = c.parameters
    edges = np.linspace(0.0, 1.0, COMBINED_BINS + 1)
    logp = {n: np.zeros(COMBINED_BINS) for n in names}
    params: dict[str, Any] = {}
    for i in c.informed_by:
        path = Path(c.refits[i].run)
        try:
            post = final_posterior(path, RunStore.open(path / "run.zarr", mode="r"))
        except (SoftsbiError, OSError, KeyError):
            continue
        u = post.unit.sample(COMBINED_DRAWS, np.random.default_rng([COMBINED_DRAWS, i]))
        for j, p in enumerate(post.space):
            if p.name in logp:
                h, _ = np.histogram(np.clip(u[:, j], 0.0, 1.0), bins=edges)
                logp[p.name] += np.log(h + 0.5)
                params.setdefault(p.name, p)
    out = []
    for n in names:
        if n not in params:
            continue
        w = np.exp(logp[n] - logp[n].max())
        w /= w.sum()
        cdf = np.concatenate([[0.0], np.cumsum(w)])
        q05, q95, mean_u = (float(np.interp(0.05, cdf, edges)), float(np.interp(0.95, cdf, edges)),
                            float(np.sum(w * (edges[:-1] + edges[1:]) / 2)))
        space = ParamSpace([params[n]])
        lo, mean, hi = (float(space.from_unit(np.array([[v]]))[0, 0]) for v in (q05, mean_u, q95))
        unit = next((e.unit for r in c.refits for e in r.estimates if e.name == n), params[n].unit)
        out.append(Estimate(name=n, unit=unit, mean=mean, q05=min(lo, hi), q95=max(lo, hi),
                            width_ratio=abs(q95 - q05), effect=c.effect))
    return tuple(out)


def load_joint_diagnosis(path: str | Path) -> JointDiagnosis:
    """Read ``joint-diagnosis.json`` (the ``--out`` folder or the file).

    Raises:
        SoftsbiError: no such file; ResultDamaged: one that cannot be read or is not a task's diagnosis.
    """
    path = Path(path)
    path = path / JOINT_FILE if path.is_dir() else path
    return read_result(path, JointDiagnosis, "task diagnosis", "a task's diagnosis",
                       f"`softsbi diagnose RUN RUN RUN ... --out {path.parent}`")
