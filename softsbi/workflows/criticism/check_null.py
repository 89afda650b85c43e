"""``check``'s omnibus test calibrated for a trained task (Hjort, Dahl & Steinbakk 2006, "Posterior predictive
p-values calibrated by the prior predictive").

The posterior predictive p-value (:func:`~softsbi.workflows.criticism.statistics.misspecification_test`) uses the recording twice,
to fit and to test, so it is not uniform under the model (Meng 1994; Bayarri & Berger 2000): a recording lies closer
to its own posterior predictive than a fresh draw does, p-values pile up near 1 and small misfits go unseen. The
calibration runs the same procedure on replicate recordings of the task: each is simulated under the model at
parameters drawn from the prior (:func:`~softsbi.workflows.measurement.simulate_recording`), observed with the fit's
observer, refitted by conditioning the task's stored estimator (the fit of a trained task does exactly that), and
checked on ``n_rollouts`` posterior-predictive rollouts (draws restricted to the prior box, as the fit's evaluation
samples are) with ``check``'s omnibus statistic under the fit's sensor model. The calibrated p-value of a recording
is the Monte-Carlo p-value of its statistic against the replicates' (:class:`CheckNull`): under the model, with
parameters drawn from the prior, the recording and the replicates are exchangeable, so it is exactly uniform and
never below ``1 / (n + 1)`` with ``n`` replicates.

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
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np

from softsbi.core.errors import PosteriorError, SimulationFailed, SoftsbiError
from softsbi.core.jsonfile import check_result_path, write_json_atomic
from softsbi.core.defaults import ALPHA
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
from softsbi.workflows.criticism.statistics import MIN_NULL, mc_pvalue, misspecification_test, trajectory_features
from softsbi.workflows.fit.task_store import StoredTask, task_store_of

#: the file beside a stored task that holds its replicates' statistics
NULL_FILE = "check-null.json"
#: the fewest replicates that can reject at the default level: ``1 / (n + 1) <= ALPHA``
MIN_REPLICATES = math.ceil(1 / ALPHA) - 1
#: replicate recordings whose posterior-predictive rollouts one executor call simulates (their rollouts are held
#: in memory together: about 30 x 0.3 MB each for the built-in lift)
BATCH = 10


@dataclass(frozen=True)
class CheckNull:
    """The omnibus statistics of a task's replicate recordings (module docstring).

    Attributes:
        rollouts: posterior-predictive rollouts per recording the statistics were computed on.
        n_dense: points per frame of the recordings' clouds (a recording's surface samples).
        statistics: ``(n,)`` the replicates' omnibus statistics (dimensionless, larger is worse).
    """

    rollouts: int
    n_dense: int
    statistics: tuple[float, ...]

    def p_value(self, statistic: float) -> MCPValue:
        """The calibrated p-value of a recording's omnibus ``statistic``: ``(1 + #{replicates >= it}) / (n + 1)``."""
        return mc_pvalue(statistic, np.asarray(self.statistics))

    def to_json(self) -> dict[str, Any]:
        """The stored form (``check-null.json``): the three attributes, as JSON."""
        return {"rollouts": self.rollouts, "n_dense": self.n_dense, "statistics": list(self.statistics)}


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
        null = CheckNull(int(d["rollouts"]), int(d["n_dense"]), tuple(float(s) for s in d["statistics"]))
        if not null.statistics or not np.all(np.isfinite(null.statistics)):
            raise ValueError("no finite statistics")
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        why = f"it lacks {exc}" if isinstance(exc, KeyError) else getattr(exc, "strerror", None) or str(exc)
        (damaged or (lambda _: None))(f"'{path}' is damaged ({why})")
        return None
    return null if null.rollouts == rollouts and null.n_dense == n_dense else None


def check_replicates(n: int) -> None:
    """Refuse a replicate count that cannot reject at the default level, before any work.

    Raises:
        SoftsbiError: ``0 < n <`` :data:`MIN_REPLICATES`."""
    if 0 < n < MIN_REPLICATES:
        raise SoftsbiError(f"--check-null {n}: a calibrated p-value from n replicates is at least 1/(n+1), so a "
                           f"level of {ALPHA} needs n >= {MIN_REPLICATES}; give --check-null 100 (or 0: none)")


def run_check_null(run: RunView, rollouts: int, say: Callable[[str], None] | None = None) -> CheckNull | None:
    """The replicates that calibrate a check of ``run`` on ``rollouts`` rollouts: those of the trained task the run
    stopped at (one round, its stored estimator conditioned on the recording), for clouds of the recording's size;
    None for a run of sequential rounds, or when the task has none for these settings. When the run's task is gone
    (deleted, damaged, its bank off) or its replicates are damaged, ``say`` is told in one line that the check is
    not calibrated, and against what its p-value is then computed."""
    rep = run.report
    if rep.rounds != 1 or not rep.per_round or rep.per_round[0].task is None:
        return None
    key = str(rep.per_round[0].task)
    store = task_store_of(run.config.sim_bank)
    entry = None if store is None else store.entry(key)

    def lost(why: str) -> None:
        (say or (lambda _: None))(
            f"check is not calibrated: {why}; its omnibus p-value is the uncalibrated posterior-predictive one "
            f"(against the run's own rollouts: it leans towards 1, so a small misfit can pass) until `softsbi task "
            f"train --check-null 100` with the fit's settings stores the task's replicates")

    if store is None:
        lost(f"the simulation bank that holds the run's task {key[:12]} is off")
    elif entry is None:
        lost(f"the run's task {key[:12]} is no longer stored in {store.path}")
    elif not isinstance(entry, StoredTask):
        lost(f"the run's task {key[:12]} in {store.path} is damaged ({entry.problem})")
    else:
        return stored_check_null(entry, rollouts, int(run.dense.shape[1]), lost)
    return None


def case_statistics(recordings: Sequence[Recording], est: Any, cfg: Any, space: ParamSpace, ctx: SimContext,
                    rollouts: int, seeds: Sequence[int], workers: int | None = None) -> np.ndarray:
    """``(n, 2)``: each recording's omnibus statistic and its uncalibrated (leave-one-out) p-value, after the
    procedure of a trained task's fit and check (module docstring); NaN for a recording that procedure could not
    check (its posterior has no mass in the prior box, or fewer than ``MIN_NULL`` of its rollouts succeeded).

    Args:
        recordings: the ``n`` recordings, with dense clouds of one size (points per frame; :func:`replicates`' are
            the task recording's). est: the task's estimator.
        cfg: the fit's settings, resolved. space: the inferred parameters. ctx: the fit's simulation context.
        rollouts: posterior-predictive rollouts per recording. seeds: one per recording (draws and rollouts).

    Raises:
        SoftsbiError: an environment fault of the executor; recordings whose clouds differ in size.
    """
    if len({int(r.dense.shape[1]) for r in recordings}) > 1:
        raise SoftsbiError("case statistics take recordings whose dense clouds hold as many points per frame")
    fr = slice(None) if cfg.frames is None else list(cfg.frames)
    sensor = metric_sensor(cfg, recordings[0].scenario)
    # as check samples a run's rollouts: as many points per frame as the recording's clouds hold (the replicates'
    # are the task recording's size), summarised in the jobs
    keep = summarising(replace(ctx, keep_rollout=False, bank=None), recordings[0].dense.shape[1],
                       sensor["metric_min_z"], sensor["metric_frames"], sensor["metric_camera"])
    out = []
    for lo in range(0, len(recordings), BATCH):
        f_obs, items = [], []
        for rec, seed in zip(recordings[lo:lo + BATCH], seeds[lo:lo + BATCH]):
            f_obs.append(trajectory_features(list(rec.dense), sensor["metric_min_z"], sensor["metric_frames"]))
            q = est.posterior_at(observe_recording(cfg, rec)[fr].astype(np.float64))
            try:
                theta = space.from_unit(draws_in_box(q, rollouts, np.random.default_rng([seed, 1])))
            except PosteriorError:  # no mass in the prior box: its fit would fail, so it is never checked
                f_obs[-1] = None
                theta = np.empty((0, space.dim))
            sim_seeds = np.random.default_rng([seed, 2]).integers(2**31, size=rollouts)
            items += [JobItem(t, int(s), summary_seed=surface_seed(i))
                      for i, (t, s) in enumerate(zip(theta, sim_seeds))]
        res = iter(run_jobs(keep, items, workers, cfg.executor, cfg.executor_options,
                            label=f"posterior-predictive rollouts of recordings {lo + 1}-{lo + len(f_obs)}"))
        for f in f_obs:
            if f is None:
                out.append((np.nan, np.nan))
                continue
            part = [next(res) for _ in range(rollouts)]
            feats = [r.features for r in part if r is not None and r.ok and r.features is not None]
            if len(feats) < MIN_NULL:  # check refuses such a run: never checked, so not a replicate either
                out.append((np.nan, np.nan))
                continue
            d, p = misspecification_test(f, np.array(feats))
            out.append((d, p.value))
    return np.array(out, float).reshape(-1, 2)


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
            out[i] = None if isinstance(res, BaseException) else res
            advance(done)
    kept = [i for i in range(n) if out[i] is not None]
    if not kept:
        raise SoftsbiError(f"every one of {n} replicate recordings failed to simulate; narrow the prior with --bounds")
    return [out[i] for i in kept], [jobs[i][-1] for i in kept]


def _simulated_recording(context: Any, job: tuple) -> Recording:
    """An executor job: :func:`~softsbi.workflows.measurement.simulate_recording` of ``job``'s arguments."""
    return simulate_recording(*job)


def train_check_null(task: StoredTask, recording: Recording, cfg: Any, space: ParamSpace, ctx: SimContext, n: int,
                     rollouts: int, workers: int | None = None,
                     message: Callable[[str], None] | None = None) -> CheckNull:
    """Compute and store the task's replicates (module docstring) for checks on ``rollouts`` rollouts.

    Raises:
        SoftsbiError: ``n`` below :data:`MIN_REPLICATES` (before any work), fewer than that could be fitted and
            checked. ResultUnwritable: ``check-null.json`` cannot be written (a folder in its place: before any
            work; a full disk named as such). Everything :func:`replicates` raises.
    """
    check_replicates(n)
    check_result_path(task.path / NULL_FILE)  # a folder in its place: refused before the replicates are fitted
    (message or (lambda s: None))(f"{task.model}: {n} replicate recordings for check's calibration "
                                  f"({n * (rollouts + 1)} simulations)")
    recs, seeds = replicates(cfg, space, recording, n)
    stats = case_statistics(recs, task.restore(), cfg, space, ctx, rollouts, seeds, workers)[:, 0]
    kept = stats[np.isfinite(stats)]
    if len(kept) < MIN_REPLICATES:
        raise SoftsbiError(f"only {len(kept)} of {n} replicate recordings could be fitted and checked (the others "
                           f"failed to simulate or put no posterior mass in the prior box); narrow the prior with "
                           f"--bounds")
    (message or (lambda s: None))(f"{task.model}: {len(kept)} of {n} replicates fitted and checked")
    null = CheckNull(rollouts, int(recording.dense.shape[1]), tuple(float(s) for s in kept))
    write_json_atomic(task.path / NULL_FILE, null.to_json())  # ResultUnwritable: one line (a full disk named)
    return null

