"""Finished runs: open a run directory for checking, diagnosing, viewing, or its posterior."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.distributions import PosteriorChain
from softsbi.core.errors import SoftsbiError, as_path
from softsbi.core.results.fitreport import FitReport
from softsbi.core.store import RunStore
from softsbi.core.types import ParamSpace, Scenario
from softsbi.plugins import registry
from softsbi.workflows.fit.bank import banks_enabled
from softsbi.workflows.fit.bestfit import BestFit, read_best_fit
from softsbi.workflows.fit.config import FitConfig, RunRecord
from softsbi.workflows.fit.report_file import read_report
from softsbi.workflows.fit.resume import observed_data
from softsbi.workflows.fit.rounds import chain_counts, round_posterior, usable_simulations
from softsbi.workflows.fit.jobs import JobItem, JobResult, SimContext, run_jobs, stored_evaluation_seeds


def read_fit_report(run_dir: str | Path) -> FitReport:
    """A finished fit's ``report.json``, typed (:class:`~softsbi.core.results.fitreport.FitReport`).

    Raises:
        ResultDamaged: it is empty, cut short, not JSON, lacks a required key or holds a value of the wrong kind;
            one line naming it and the fit's own command, which writes it again.
    """
    run_dir = Path(run_dir)
    return FitReport.from_json(read_report(run_dir), run_dir / "report.json")


@dataclass(kw_only=True)
class RunView:
    """What the diagnostics need from a finished run, loaded once (:func:`load_run`) and passed down a command.

    Attributes:
        path: the run directory. config: the fit's settings (:class:`~softsbi.workflows.fit.config.FitConfig`,
            :meth:`~softsbi.workflows.fit.config.FitConfig.from_run_config`). record: what the run stored beside
            them: its recording's scenario, observer options, source and truth, its metric
            (:class:`~softsbi.workflows.fit.config.RunRecord`). space: the inferred parameters.
        scenario, dense (``T`` clouds ``(m, 3)`` m), x_obs: the measurement as fitted.
        report: ``report.json`` (:class:`~softsbi.core.results.fitreport.FitReport`).
        post_theta: ``(S, D)`` the fit's evaluation samples (physical units), the first ``n_eval``.
        post_seeds: ``(S,)`` their simulation seeds. post_complete: ``post_theta`` holds every stored sample.
    """

    path: Path
    config: FitConfig
    record: RunRecord
    space: ParamSpace
    scenario: Scenario
    dense: np.ndarray
    x_obs: np.ndarray
    report: FitReport
    post_theta: np.ndarray  # (S, D) posterior samples (inferred params), physical units
    post_seeds: np.ndarray | None = None  # (S,) their simulation seeds in the fit's evaluation
    post_complete: bool = True
    _posterior: "Posterior | None" = field(default=None, repr=False, compare=False)

    def posterior(self) -> "Posterior":
        """The fit's final posterior in physical units (:class:`Posterior`, built from the store once)."""
        if self._posterior is None:
            self._posterior = final_posterior(self.path, RunStore.open(self.path / "run.zarr"))
        return self._posterior

    def sim_context(self, keep_rollout: bool = True) -> Any:
        """The fit's own worker context (:class:`~softsbi.workflows.fit.run.SimContext`): same simulator,
        observer and metric, so re-simulating the fit's evaluation samples reproduces its Chamfer. Its rollouts go
        through the run's own simulation bank (``RUN/sims.zarr``): ``check``, ``diagnose``, ``compare`` and
        ``view`` simulate each posterior-predictive rollout and finite difference once."""
        c, rec = self.config, self.record
        return SimContext(backend=c.backend, backend_options=dict(c.backend_options), scenario=rec.scenario,
                          effects=list(self.effects), observer=c.observer,
                          observer_options=dict(rec.observer_options), param_names=self.space.names,
                          fixed=self.fixed, dense=self.dense, n_dense=int(c.n_dense), keep_rollout=keep_rollout,
                          min_z=rec.metric_min_z, camera=rec.metric_camera,
                          bank=str(self.path / "sims.zarr") if banks_enabled() else None)

    @property
    def metric_min_z(self) -> float | None:
        """The fit's sensor model for the metric: points at or below this height (m) are not seen;
        None = full clouds (also runs written before the metric had a sensor model)."""
        return self.record.metric_min_z

    @property
    def metric_frames(self) -> list[int] | None:
        """The frames the fit's headline Chamfer averages (None = all)."""
        return self.record.metric_frames

    def posterior_rollouts(self, workers: int | None = None) -> tuple[list[JobResult], list[JobResult]]:
        """Re-simulate the run's posterior samples (:attr:`post_theta`) with their seeds through the
        fit's own job, so each rollout's per-frame Chamfer is the fit's metric.

        Returns:
            ``(ok, results)``: the successful rollouts (job results with ``vertices (T, N, 3)`` m,
            ``faces``, ``gripper``, ``chamfer (T,)``, ``seed``, and ``sample`` = the row of
            :attr:`post_theta`) and every job result, in sample order.
        """
        items = [JobItem(theta, int(seed)) for theta, seed in zip(self.post_theta, self.post_seeds)]
        res = run_jobs(self.sim_context(keep_rollout=True), items, workers, label="posterior rollouts")
        ok = [replace(r, sample=i) for i, r in enumerate(res) if r is not None and r.ok and r.vertices is not None]
        return ok, res

    @property
    def fixed(self) -> dict[str, float]:
        """Parameters held fixed in the fit ``{name: value}``."""
        return dict(self.config.fixed)

    @property
    def effects(self) -> list[str]:
        """Effects the fit switched on."""
        return list(self.config.effects)

    def values(self, row: np.ndarray) -> dict[str, float]:
        """Inferred parameters ``(D,)`` plus the fixed ones as a ``{name: value}`` mapping."""
        v = self.space.as_dict(row)
        v.update(self.fixed)
        return v

    def median(self) -> dict[str, float]:
        """Posterior median (physical units) plus the fixed parameters."""
        v = {k: float(x) for k, x in self.report.posterior_median.items()}
        v.update(self.fixed)
        return v



def load_run(run_dir: str | Path, n_eval: int | None = 30, seed: int = 0) -> RunView:
    """Open a finished fit (``run.zarr`` + ``report.json``) for checking: its first ``n_eval`` evaluation samples
    (None: all of them, what ``check`` and ``diagnose`` load so that their null shares the run).

    Raises:
        SchemaError: not a run; SoftsbiError: the fit has not finished (no report.json); ResultDamaged: its
            report.json is damaged (:func:`read_report`); ObservedDamaged: its observed state is damaged and cannot
            be rebuilt from the recording (:func:`~softsbi.workflows.fit.resume.observed_data`).
    """
    run_dir = Path(run_dir)
    store = RunStore.open(run_dir / "run.zarr")
    rep_path = run_dir / "report.json"
    if not rep_path.exists():
        raise SoftsbiError(f"'{run_dir}' has no report.json: the fit has not finished; resume it with the same "
                           f"`softsbi fit ... --out {run_dir}` command first")
    report = read_fit_report(run_dir)
    cfg, rec = FitConfig.from_run_config(store.config), RunRecord.from_run_config(store.config)
    obs = None if rec.image_fit else observed_data(store)  # damaged: rebuilt, said
    if obs is None or "dense" not in obs:
        raise SoftsbiError(f"'{run_dir}' is an image fit (observer '{cfg.observer}'): check, diagnose and "
                           f"compare work on point-cloud fits, which carry 3-D clouds to localise the error; "
                           f"its report.json holds the mask Chamfer of prior and posterior rollouts")
    space = ParamSpace.from_json(rec.param_space)
    if store.has("evaluation"):
        ev, ev_attrs = store.read_group("evaluation", ("theta",))  # what is re-simulated: the samples
        stored = len(ev["theta"])
        theta = ev["theta"][:n_eval]
        # the rounds the evaluation followed (stored with it; older runs: the latest session's)
        seeds = stored_evaluation_seeds(int(cfg.seed), ev_attrs, rec.rounds, len(ev["theta"]))[:n_eval]
    else:  # fall back on the last round's draws (samples of the previous posterior)
        last = store.round_ids()[-1]
        d = store.round_data(last)
        stored = len(d["theta"])
        theta, seeds = d["theta"][:n_eval], d["seed"][:n_eval]
    return RunView(path=run_dir, config=cfg, record=rec, space=space, scenario=Scenario.from_json(rec.scenario),
                   dense=obs["dense"], x_obs=obs["x"], report=report, post_theta=theta, post_seeds=np.asarray(seeds),
                   post_complete=len(theta) == stored)




# ----------------------------------------------------------------------------------------
# a finished run's posterior, in physical units (the public API's ``softsbi.open_run``)


class Posterior:
    """A fit's final posterior over the inferred parameters, in physical units.

    Wraps the posterior the fit computed in unit coordinates (``u`` in ``[0, 1]^D``, log scale
    for log-scaled parameters; see :class:`~softsbi.core.types.ParamSpace`) and maps it to the
    parameters' own units.

    Attributes:
        space: the inferred :class:`~softsbi.core.types.ParamSpace` (names, units, prior box).
        unit: the posterior in unit coordinates (``sample(n, rng)``, ``log_prob(u)``).
    """

    def __init__(self, space: ParamSpace, unit: Any, seed: int = 0):
        self.space, self.unit, self._seed = space, unit, seed
        self._draws: np.ndarray | None = None

    @property
    def names(self) -> list[str]:
        """Parameter names, in column order."""
        return self.space.names

    def sample(self, n: int, seed: int = 0) -> np.ndarray:
        """``(n, D)`` posterior draws in physical units (columns in :attr:`names` order)."""
        return self.space.from_unit(self.unit.sample(int(n), np.random.default_rng([self._seed, 7, int(seed)])))

    def log_prob(self, theta: np.ndarray) -> np.ndarray:
        """Log posterior density ``(n,)`` at ``theta (n, D)`` in physical units: the unit-coordinate
        density plus ``log |du/dtheta|`` (``1 / (high - low)``, or ``1 / (theta log(high / low))``
        for log-scaled parameters); ``-inf`` outside the prior box.

        Raises:
            ShapeError: ``theta`` does not have D columns.
        """
        theta = np.atleast_2d(np.asarray(theta, float))
        u = self.space.to_unit(theta)
        lo, hi, lg = self.space._t()
        with np.errstate(divide="ignore", invalid="ignore"):
            jac = np.where(lg, -np.log(np.abs(theta)) - np.log(hi - lo), -np.log(hi - lo)).sum(-1)
            return self.unit.log_prob(u) + jac

    def _samples(self) -> np.ndarray:
        if self._draws is None:
            self._draws = self.sample(4000)
        return self._draws

    @property
    def mean(self) -> dict[str, float]:
        """Posterior mean per parameter (physical units; 4000 draws)."""
        return self.space.as_dict(self._samples().mean(0))

    def interval(self, level: float = 0.9) -> dict[str, tuple[float, float]]:
        """Central ``level`` credible interval per parameter ``{name: (low, high)}`` (physical units).

        Raises:
            SoftsbiError: ``level`` outside (0, 1).
        """
        if not 0 < level < 1:
            raise SoftsbiError(f"interval level must lie in (0, 1) (got {level})")
        s = self._samples()
        lo = np.quantile(s, (1 - level) / 2, axis=0)
        hi = np.quantile(s, (1 + level) / 2, axis=0)
        return {n: (float(a), float(b)) for n, a, b in zip(self.names, lo, hi)}


@dataclass
class Run:
    """A fit's run directory, opened (:func:`open_run`).

    Attributes:
        path: the run directory. config: the fit's settings (:class:`~softsbi.workflows.fit.run.FitConfig`).
        report: ``report.json`` (:class:`~softsbi.core.results.fitreport.FitReport`, e.g.
            ``run.report.chamfer_posterior_m``; None while the fit has not finished). space: the inferred parameters.
        posterior: the final posterior in physical units (:class:`Posterior`).
        best_fit: the best-fitting parameters the fit found and their rollout
            (:class:`~softsbi.workflows.fit.bestfit.BestFit`), None for a run that stored none.
    """

    path: Path
    config: Any
    report: FitReport | None
    space: ParamSpace
    posterior: Posterior
    best_fit: BestFit | None = None


def open_run(run_dir: str | Path) -> Run:
    """Open a fit's run directory: its settings, report, final posterior in physical units and best fit.

    The posterior is rebuilt from the stored rounds exactly as the fit built it (the corrected
    chain of round posteriors, or the last round's ``q`` restricted to the prior box for truncated
    proposals and bulk estimators), whatever the estimator: a Gaussian mixture from its stored arrays,
    any other posterior (e.g. ``flow``) from the estimator's stored state
    (:func:`~softsbi.workflows.fit.run.round_posterior`).

    Raises:
        SchemaError: not a run directory (no ``run.zarr``) or an unreadable schema version;
            ``PosteriorDamaged`` (a SchemaError): a stored posterior is missing or damaged.
        SoftsbiError: no round has finished yet (resume the fit first). ParameterError: ``run_dir`` is not a path
            (e.g. None).
    """
    run_dir = as_path(run_dir, "open_run(run_dir)", 'softsbi.open_run("runs/tan")')
    store = RunStore.open(run_dir / "run.zarr")
    post = final_posterior(run_dir, store)
    report = read_fit_report(run_dir) if (run_dir / "report.json").exists() else None
    return Run(path=run_dir, config=FitConfig.from_run_config(store.config), report=report, space=post.space,
               posterior=post, best_fit=read_best_fit(store))


def final_posterior(run_dir: Path, store: RunStore) -> Posterior:
    """The run's final posterior in physical units, rebuilt from its stored rounds as the fit built it
    (:func:`open_run`).

    Raises:
        SoftsbiError: no round has finished yet. PosteriorDamaged: a stored posterior is missing or damaged.
    """
    cfg = FitConfig.from_run_config(store.config)
    space = ParamSpace.from_json(store.config["param_space"])
    rounds = [r for r in store.completed_rounds()]
    if not rounds:
        raise SoftsbiError(f"'{run_dir}' holds no finished round yet; resume the fit with the same `softsbi fit` "
                           f"command first")
    sequential = bool(getattr(registry().estimator(cfg.estimator), "sequential", True))
    counts = chain_counts(store, usable_simulations(store, rounds[-1])[2])
    chain = PosteriorChain(space.dim, seed=cfg.seed)
    if sequential and cfg.proposal != "truncated":
        for r in rounds:
            chain.add_round(round_posterior(store, r, cfg), counts[r])
    else:
        chain.add_round(round_posterior(store, rounds[-1], cfg), sum(counts))
    return Posterior(space, chain.posterior(len(chain) - 1), seed=cfg.seed)
