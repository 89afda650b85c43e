"""``check``'s test calibrated for a trained task (Hjort, Dahl & Steinbakk 2006, "Posterior predictive
p-values calibrated by the prior predictive").

The posterior predictive p-value (:func:`~softsbi.workflows.criticism.statistics.misspecification_test`) uses the recording twice,
to fit and to test, so it is not uniform under the model (Meng 1994; Bayarri & Berger 2000): a recording lies closer
to its own posterior predictive than a fresh draw does, p-values pile up near 1 and small misfits go unseen. The
calibration runs the same procedure on replicate recordings of the task: each is simulated under the model at
parameters drawn from the prior (:func:`~softsbi.workflows.measurement.simulate_recording`), observed with the fit's
observer, refitted by conditioning the task's stored estimator (the fit of a trained task does exactly that), and
checked on ``n_rollouts`` posterior-predictive rollouts (draws restricted to the prior box, as the fit's evaluation
samples are) with ``check``'s omnibus statistic under the fit's sensor model, and screened about its posterior
median against the candidate family (every candidate's directional statistic). The calibrated p-value of a recording
is the min-p combination of its two statistics against the replicates' pairs (:meth:`CheckNull.joint_p_value`; the
omnibus statistic alone against theirs when the check has no family): under the model, with parameters drawn from
the prior, the recording and the replicates are exchangeable, so it is exactly uniform and never below
``1 / (n + 1)`` with ``n`` replicates.

It applies to a run that stopped at its trained task (one round: the stored estimator conditioned on the
recording) and was checked on the same number of rollouts, with the same number of points per cloud. Each trained
model has its own: the nominal model's calibrate ``diagnose``'s detection, a candidate model's the check of its
refit (the candidate's amortised posterior on a trained task), so that a refit is judged adequate with the power the
nominal model was rejected with. The replicates are stored beside the task (``BANK/tasks/KEY/check-null.json``) and
go with it: a retrained task has none until ``softsbi task train --check-null N`` computes them again.
"""
from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np

from softsbi.core.errors import PosteriorError, SimulationFailed, SoftsbiError
from softsbi.core.jsonfile import check_result_path, write_json_atomic
from softsbi.core.defaults import ALPHA, MAX_CHECK_REPLICATES, MIN_CHECK_REPLICATES
from softsbi.core.results import MCPValue
from softsbi.core.types import ParamSpace, Recording
from softsbi.core.seeds import NULL_STREAM, surface_seed
from softsbi.inference.calibration import draws_in_box
from softsbi.workflows import pools
from softsbi.workflows.fit.jobs import JobItem, SimContext, run_jobs
from softsbi.workflows.measurement import simulate_recording
from softsbi.workflows.fit.observe import metric_sensor, observe_recording
from softsbi.workflows.reporting import phase
from softsbi.workflows.fit.runs import RunView
from softsbi.workflows.criticism.stats import summarising
from softsbi.workflows.criticism.statistics import (MIN_NULL, mc_pvalue, min_p_combined, misspecification_test,
                                                     trajectory_features)
from softsbi.workflows.fit.task_store import StoredTask, task_store_of

#: the file beside a stored task that holds its replicates' statistics
NULL_FILE = "check-null.json"
#: the fewest replicates that can reject at the default level: ``1 / (n + 1) <= ALPHA``
MIN_REPLICATES = MIN_CHECK_REPLICATES
#: posterior draws a replicate's posterior median is taken from (a fit's report takes it from 4000 samples)
MEDIAN_DRAWS = 4000
#: replicate recordings whose posterior-predictive rollouts one executor call simulates (their rollouts are held
#: in memory together: about 30 x 0.3 MB each for the built-in lift)
BATCH = 10


@dataclass(frozen=True)
class CheckNull:
    """The check statistics of a task's replicate recordings (module docstring).

    Attributes:
        rollouts: posterior-predictive rollouts per recording the statistics were computed on.
        n_dense: points per frame of the recordings' clouds (a recording's surface samples).
        statistics: ``(n,)`` the replicates' omnibus statistics (dimensionless, larger is worse).
        directional: ``(n, C)`` each replicate's normalised max-T statistic of each candidate of ``family``
            (:func:`~softsbi.workflows.criticism.statistics.max_t_statistics`; NaN where that candidate's screening
            failed), in the order of ``statistics``: the directional statistic of a check against any part of the
            family is their maximum over that part; None for replicates stored before the joint calibration.
        family: the candidates of ``directional``'s columns.
    """

    rollouts: int
    n_dense: int
    statistics: tuple[float, ...]
    directional: tuple[tuple[float, ...], ...] | None = None
    family: tuple[str, ...] | None = None

    def p_value(self, statistic: float) -> MCPValue:
        """The calibrated p-value of a recording's omnibus ``statistic``: ``(1 + #{replicates >= it}) / (n + 1)``."""
        return mc_pvalue(statistic, np.asarray(self.statistics))

    def calibrates(self, family: Sequence[str]) -> bool:
        """Whether these replicates calibrate a check against the candidate ``family``: the omnibus test alone (no
        family), or both tests when every candidate of ``family`` was screened on the replicates (a refit's check
        screens the family less its own effects: a part of it)."""
        return not family or (self.directional is not None and set(family) <= set(self.family or ()))

    def joint_p_value(self, pair: np.ndarray, family: Sequence[str]) -> MCPValue:
        """The calibrated joint p-value of a recording's ``(omnibus, directional)`` statistics, its directional one
        the maximum over ``family`` (:meth:`calibrates`): their min-p combination against the replicates' pairs
        (:func:`~softsbi.workflows.criticism.statistics.min_p_combined`), exactly uniform under the model (the
        recording and the replicates are exchangeable). A replicate none of whose ``family`` could be screened is
        left out.

        Raises:
            SoftsbiError: replicates that do not calibrate a check against ``family``."""
        if not family or not self.calibrates(family):
            raise SoftsbiError(f"these replicates were not screened against {list(family)}; compute them again with "
                               f"`softsbi task train --check-null 100`")
        cols = [list(self.family or ()).index(c) for c in family]
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a replicate none of whose family was screened
            z = np.nanmax(np.asarray(self.directional, float)[:, cols], axis=1)
        ok = np.isfinite(z)
        return min_p_combined(pair, np.column_stack([np.asarray(self.statistics)[ok], z[ok]]))

    def to_json(self) -> dict[str, Any]:
        """The stored form (``check-null.json``): the attributes, as JSON (NaN as null)."""
        return {"rollouts": self.rollouts, "n_dense": self.n_dense, "statistics": list(self.statistics),
                "directional": None if self.directional is None else [
                    [None if not math.isfinite(v) else v for v in row] for row in self.directional],
                "family": None if self.family is None else list(self.family)}


def stored_check_null(task: StoredTask | None, rollouts: int, n_dense: int,
                      damaged: Callable[[str], None] | None = None) -> CheckNull | None:
    """The task's replicates for checks on ``rollouts`` rollouts of ``n_dense``-point clouds; None when the task
    has none, or none for these settings, or the file cannot be read (a damaged file is computed again), which is
    told to ``damaged`` (what is wrong with the file, one line)."""
    if task is None or not (task.path / NULL_FILE).is_file():
        return None
    path = task.path / NULL_FILE
    try:
        d = json.loads(path.read_text())
        direc, fam = d.get("directional"), d.get("family")
        null = CheckNull(int(d["rollouts"]), int(d["n_dense"]), tuple(float(s) for s in d["statistics"]),
                         None if direc is None else tuple(tuple(float("nan") if v is None else float(v) for v in row)
                                                          for row in direc),
                         None if fam is None else tuple(str(f) for f in fam))
        if not null.statistics or not np.all(np.isfinite(null.statistics)):
            raise ValueError("no finite statistics")
        if null.directional is not None and (len(null.directional) != len(null.statistics)
                                             or any(len(row) != len(null.family or ()) for row in null.directional)):
            raise ValueError("directional statistics that do not match the omnibus ones and the family")
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        why = f"it lacks {exc}" if isinstance(exc, KeyError) else getattr(exc, "strerror", None) or str(exc)
        (damaged or (lambda _: None))(f"'{path}' is damaged ({why})")
        return None
    return null if null.rollouts == rollouts and null.n_dense == n_dense else None


def check_replicates(n: int, flag: str = "--check-null") -> None:
    """Refuse a replicate count (of option ``flag``) that cannot reject at the default level, before any work.

    Raises:
        SoftsbiError: ``0 < n <`` :data:`MIN_REPLICATES`."""
    if 0 < n < MIN_REPLICATES:
        raise SoftsbiError(f"{flag} {n}: a calibrated p-value from n replicates is at least 1/(n+1), so a "
                           f"level of {ALPHA} needs n >= {MIN_REPLICATES}; give {flag} {'100' if flag == '--check-null' else MIN_REPLICATES} (or 0: none)")


def run_check_null(run: RunView, rollouts: int, say: Callable[[str], None] | None = None,
                   family: Sequence[str] = ()) -> CheckNull | None:
    """The replicates that calibrate a check of ``run`` on ``rollouts`` rollouts against the candidate ``family``:
    those of the trained task the run stopped at (one round, its stored estimator conditioned on the recording), for
    clouds of the recording's size and checked against the same family (:meth:`CheckNull.calibrates`), or not
    screened at all (a candidate model's, ``task train --refit-null``: they calibrate the omnibus test alone, and the
    check then screens no family); None for a
    run of sequential rounds, or when the task has none for these settings. When the run's task is gone (deleted,
    damaged, its bank off), its replicates are damaged or were checked against another family, ``say`` is told in
    one line that the check is not calibrated, and against what its p-value is then computed."""
    rep = run.report
    if rep.rounds != 1 or not rep.per_round or rep.per_round[0].task is None:
        return None
    key = str(rep.per_round[0].task)
    store = task_store_of(run.config.sim_bank)
    entry = None if store is None else store.entry(key)

    def lost(why: str) -> None:
        (say or (lambda _: None))(
            f"check is not calibrated: {why}; its p-value is the uncalibrated posterior-predictive one (against the "
            f"run's own rollouts: it leans towards 1, so a small misfit can pass) until `softsbi task train "
            f"--check-null 100` with the fit's settings stores the task's replicates")

    if store is None:
        lost(f"the simulation bank that holds the run's task {key[:12]} is off")
    elif entry is None:
        lost(f"the run's task {key[:12]} is no longer stored in {store.path}")
    elif not isinstance(entry, StoredTask):
        lost(f"the run's task {key[:12]} in {store.path} is damaged ({entry.problem})")
    else:
        null = stored_check_null(entry, rollouts, int(run.dense.shape[1]), lost)
        if null is None or null.calibrates(family) or null.directional is None:
            return null  # unscreened replicates calibrate the omnibus test alone (check_run then screens nothing)
        lost(f"the task's {len(null.statistics)} replicates were checked against another candidate family "
             f"({len(null.family or ())} candidates, this check {len(family)})")
    return None


def case_statistics(recordings: Sequence[Recording], est: Any, cfg: Any, space: ParamSpace, ctx: SimContext,
                    rollouts: int, seeds: Sequence[int], workers: int | None = None,
                    family: Sequence[Any] = ()) -> np.ndarray:
    """``(n, 2 + C)``: each recording's omnibus statistic, its uncalibrated (leave-one-out) p-value and its
    directional statistics against the ``C`` candidates of ``family`` (effect instances; each one's normalised max-T
    statistic about the recording's posterior median, :func:`~softsbi.workflows.criticism.screening.
    screening_statistics`), after the procedure of a trained task's fit and check (module docstring); NaN for a
    recording that procedure could not check (its posterior has no mass in the prior box, or fewer than
    ``MIN_NULL`` of its rollouts succeeded), and a directional NaN where its screening of a candidate failed.

    Args:
        recordings: the ``n`` recordings, with dense clouds of one size (points per frame; :func:`replicates`' are
            the task recording's). est: the task's estimator.
        cfg: the fit's settings, resolved. space: the inferred parameters. ctx: the fit's simulation context.
        rollouts: posterior-predictive rollouts per recording. seeds: one per recording (draws and rollouts).
        family: the check's candidate effects; each recording's screening costs ``1 + dim`` simulations plus one
            per candidate and one per candidate parameter (:func:`~softsbi.workflows.criticism.screening.
            sensitivity_jobs`).

    Raises:
        SoftsbiError: an environment fault of the executor; recordings whose clouds differ in size.
    """
    return _case_statistics(recordings, est, cfg, space, ctx, rollouts, seeds, workers, family)[0]


def _case_statistics(recordings: Sequence[Recording], est: Any, cfg: Any, space: ParamSpace, ctx: SimContext,
                     rollouts: int, seeds: Sequence[int], workers: int | None = None,
                     family: Sequence[Any] = ()) -> tuple[np.ndarray, list[str]]:
    """:func:`case_statistics`, and per recording why its fit could not be checked (``""``: it was checked)."""
    from softsbi.workflows.criticism.screening import screening_statistics  # screening reads check's statistics
    if len({int(r.dense.shape[1]) for r in recordings}) > 1:
        raise SoftsbiError("case statistics take recordings whose dense clouds hold as many points per frame")
    fr = slice(None) if cfg.frames is None else list(cfg.frames)
    sensor = metric_sensor(cfg, recordings[0].scenario)
    # as check samples a run's rollouts: as many points per frame as the recording's clouds hold (the replicates'
    # are the task recording's size), summarised in the jobs
    keep = summarising(replace(ctx, keep_rollout=False, bank=None), recordings[0].dense.shape[1],
                       sensor["metric_min_z"], sensor["metric_frames"], sensor["metric_camera"])
    out, why = [], []
    for lo in range(0, len(recordings), BATCH):
        f_obs, items, medians = [], [], []
        for rec, seed in zip(recordings[lo:lo + BATCH], seeds[lo:lo + BATCH]):
            f_obs.append(trajectory_features(list(rec.dense), sensor["metric_min_z"], sensor["metric_frames"]))
            q = est.posterior_at(observe_recording(cfg, rec)[fr].astype(np.float64))
            try:
                theta = space.from_unit(draws_in_box(q, rollouts, np.random.default_rng([seed, 1])))
                # the fit's posterior median (report.json's, the screening's linearisation point)
                medians.append({**space.as_dict(np.median(space.from_unit(
                    draws_in_box(q, MEDIAN_DRAWS, np.random.default_rng([seed, 3]))), axis=0)), **dict(cfg.fixed)})
            except PosteriorError:  # no mass in the prior box: its fit would fail, so it is never checked
                f_obs[-1], theta = None, np.empty((0, space.dim))
                medians.append(None)
            sim_seeds = np.random.default_rng([seed, 2]).integers(2**31, size=rollouts)
            items += [JobItem(t, int(s), summary_seed=surface_seed(i))
                      for i, (t, s) in enumerate(zip(theta, sim_seeds))]
        res = iter(run_jobs(keep, items, workers, cfg.executor, cfg.executor_options,
                            label=f"posterior-predictive rollouts of recordings {lo + 1}-{lo + len(f_obs)}"))
        checked = []  # (f_obs, null features, median) of the batch's recordings that can be checked
        for f, med in zip(f_obs, medians):
            part = [next(res) for _ in range(rollouts)] if f is not None else []
            feats = [r.features for r in part if r is not None and r.ok and r.features is not None]
            # check refuses a run with too few rollouts: never checked, so not a replicate either
            checked.append((f, np.array(feats), med) if f is not None and len(feats) >= MIN_NULL else None)
            why.append("" if checked[-1] else "its posterior has no mass in the prior box" if f is None else
                       f"only {len(feats)} of its {rollouts} posterior-predictive rollouts ran (a check needs "
                       f"{MIN_NULL})")
        z = screening_statistics(keep, space, cfg, [c[2] if c else None for c in checked],
                                 [c[0] if c else None for c in checked], [c[1] if c else None for c in checked],
                                 list(family), workers, label=f"screenings of recordings {lo + 1}-{lo + len(f_obs)}")
        for c, zz in zip(checked, z):
            if c is None:
                out.append([np.nan, np.nan, *zz])
                continue
            d, p = misspecification_test(c[0], c[1])
            out.append([d, p.value, *zz])
    return np.array(out, float).reshape(-1, 2 + len(family)), why


def replicates(cfg: Any, space: ParamSpace, recording: Recording, n: int, stream: int = NULL_STREAM,
               effects: Sequence[str] = (), extra: dict[str, float] | None = None
               ) -> tuple[list[Recording], list[int]]:
    """Recordings of the task simulated under its model (``cfg.effects`` on) at ``n`` parameters drawn from the
    prior (recording ``i`` from the seed stream ``[cfg.seed, stream, i]``), with ``effects`` switched on besides at
    the values ``extra`` (a hidden effect; none for replicates), on the fit's executor; their clouds hold as many
    points per frame as ``recording``'s. A
    simulation that fails gives no recording (a recording is a simulation that ran): the lists hold the others,
    with their seeds.

    Raises:
        SoftsbiError: every simulation failed, or the executor raised one (an environment fault)."""
    jobs, out = _replicate_runs(cfg, space, recording, n, stream, effects, extra)
    kept = [i for i in range(n) if isinstance(out[i], Recording)]
    if not kept:
        raise SoftsbiError(f"every one of {n} replicate recordings failed to simulate; narrow the prior with --bounds")
    return [out[i] for i in kept], [jobs[i][-1] for i in kept]


def _replicate_runs(cfg: Any, space: ParamSpace, recording: Recording, n: int, stream: int = NULL_STREAM,
                    effects: Sequence[str] = (), extra: dict[str, float] | None = None
                    ) -> tuple[list[tuple], list[Recording | BaseException]]:
    """:func:`replicates`' simulation jobs (:func:`~softsbi.workflows.measurement.simulate_recording`'s arguments,
    the truth third and the seed last) and, per replicate, its recording or the exception its simulation ended in.

    Raises:
        SoftsbiError: the executor raised one (an environment fault)."""
    jobs = []
    for i in range(n):  # recording i's own stream: the first n of a larger set are these n
        rng = np.random.default_rng([cfg.seed, stream, i])
        truth = {**space.as_dict(space.from_unit(rng.random((1, space.dim)))[0]), **dict(cfg.fixed),
                 **dict(extra or {})}
        jobs.append((cfg.backend, recording.scenario, truth, dict(cfg.backend_options),
                     list(cfg.effects) + [e for e in effects if e not in cfg.effects], cfg.n_points,
                     int(recording.dense.shape[1]), 0.0, int(rng.integers(2**31))))
    out: list[Any] = [None] * n
    with pools.executor(cfg.executor, cfg.workers, cfg.executor_options) as exe, \
            phase("replicate recordings", n) as advance:
        for done, (i, res) in enumerate(exe.map_unordered(_simulated_recording, jobs), start=1):
            if isinstance(res, SoftsbiError) and not isinstance(res, SimulationFailed):
                raise res
            out[i] = res
            advance(done)
    return jobs, out


def _simulated_recording(context: Any, job: tuple) -> Recording:
    """An executor job: :func:`~softsbi.workflows.measurement.simulate_recording` of ``job``'s arguments."""
    return simulate_recording(*job)


def train_check_null(task: StoredTask, recording: Recording, cfg: Any, space: ParamSpace, ctx: SimContext, n: int,
                     rollouts: int, workers: int | None = None,
                     message: Callable[[str], None] | None = None, family: Sequence[Any] | None = None) -> CheckNull:
    """Compute and store the task's replicates (module docstring) for checks on ``rollouts`` rollouts against any
    part of the candidate ``family`` (effect instances; None: the model's default family,
    :func:`~softsbi.workflows.criticism.screening.default_candidates`, the family ``check`` and ``diagnose`` screen):
    each replicate's omnibus and directional statistics (:func:`case_statistics`).

    A replicate that cannot be fitted and checked as a recording would be (its simulation failed, its posterior has
    no mass in the prior box, too few of its rollouts ran, or none of the family could be screened) is left out, so
    that the pairs stay the recording's procedure; the others are kept when at least :data:`MIN_REPLICATES` are left
    (a p-value from ``k`` replicates is at least ``1 / (k + 1)``: fewer cannot resolve the level), and the left-out
    ones are named to ``message``, each with its parameters and reason.

    Raises:
        SoftsbiError: ``n`` below :data:`MIN_REPLICATES` (before any work); fewer than that could be fitted and
            checked (one line naming the model and the first failed replicates: index, parameters, reason).
            ResultUnwritable: ``check-null.json`` cannot be written (a folder in its place: before any work; a full
            disk named as such). Everything :func:`replicates` raises but its "every simulation failed".
    """
    from softsbi.workflows.criticism.screening import default_candidates, screening_size  # screening reads this
    say = message or (lambda s: None)
    check_replicates(n)
    check_result_path(task.path / NULL_FILE)  # a folder in its place: refused before the replicates are fitted
    family = list(default_candidates(cfg.backend, recording.scenario, cfg.effects) if family is None else family)
    per = rollouts + 1 + screening_size(space.dim, family)
    say(f"{task.model}: {n} replicate recordings for check's calibration ({n * per} simulations: each simulated, "
        f"{rollouts} posterior-predictive rollouts and its screening of {len(family)} candidates)")
    jobs, sims = _replicate_runs(cfg, space, recording, n)
    why = {i: str(sim) if isinstance(sim, SimulationFailed) else f"its simulation failed ({type(sim).__name__}: {sim})"
           for i, sim in enumerate(sims) if not isinstance(sim, Recording)}
    ran = [i for i in range(n) if i not in why]
    stats = np.full((0, 2 + len(family)), np.nan)
    if ran:
        stats, reasons = _case_statistics([sims[i] for i in ran], task.restore(), cfg, space, ctx, rollouts,
                                          [jobs[i][-1] for i in ran], workers, family)
        for i, row, reason in zip(ran, stats, reasons):
            if reason or (family and not np.isfinite(row[2:]).any()):
                why[i] = reason or f"none of its {len(family)} candidates could be screened"
    ok = [k for k, i in enumerate(ran) if i not in why]
    failed = "; ".join(f"replicate {i + 1} at {_at(jobs[i][2], space)}: {why[i]}" for i in sorted(why)[:3]) + (
        f"; and {len(why) - 3} more" if len(why) > 3 else "")
    if len(ok) < MIN_REPLICATES:
        enough = math.ceil(MIN_REPLICATES * n / len(ok)) + 1 if ok else MAX_CHECK_REPLICATES + 1  # at this rate
        more = f"give --check-null {enough} (the failed ones are left out) or " if enough <= MAX_CHECK_REPLICATES else ""
        raise SoftsbiError(f"{task.model}: only {len(ok)} of {n} replicate recordings could be fitted and checked, and "
                           f"check's calibration needs {MIN_REPLICATES} (a p-value from k replicates is at least "
                           f"1/(k+1), above the level {ALPHA} for fewer): {failed}; {more}narrow the prior with "
                           f"--bounds")
    say(f"{task.model}: {len(ok)} of {n} replicates fitted and checked" + (
        f", kept (check's calibration needs at least {MIN_REPLICATES}); left out: {failed}" if why else ""))
    null = CheckNull(rollouts, int(recording.dense.shape[1]), tuple(float(v) for v in stats[ok, 0]),
                     tuple(tuple(float(v) for v in row) for row in stats[ok, 2:]) if family else None,
                     tuple(c.name for c in family) if family else None)
    write_json_atomic(task.path / NULL_FILE, null.to_json())  # ResultUnwritable: one line (a full disk named)
    return null


def _at(truth: dict[str, float], space: ParamSpace) -> str:
    """A replicate's inferred parameters, e.g. ``a=0.93, b=-0.2``."""
    return ", ".join(f"{k}={float(truth[k]):.4g}" for k in space.names)
