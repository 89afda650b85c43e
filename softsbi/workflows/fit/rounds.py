"""The sequential rounds of a fit (:class:`Rounds`): draw each round's proposal, simulate what is pending (through
the simulation bank for the first round), train the estimator on every usable simulation so far and condition it
on the observation; ``sensor_draws`` (:class:`SensorDraws`); the stored posterior of a round
(:func:`round_posterior`).
"""
from __future__ import annotations

import contextlib
import inspect
from dataclasses import replace
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.core.distributions import MixtureOfGaussians, PosteriorChain, RoundPosterior, TruncatedPrior
from softsbi.core.errors import EffectFault, PosteriorDamaged, PosteriorError, SoftsbiError
from softsbi.core.interfaces import OBSERVATION
from softsbi.core.store import ROUND_ARRAYS, EstimatorState, RunStore
from softsbi.core.types import STATUS_ERROR, STATUS_OK, ParamSpace
from softsbi.executors.local import WorkerFailure
from softsbi.plugins import registry
from softsbi.workflows.fit.bank import BankCount, bank_folder
from softsbi.workflows.fit.config import FitConfig, RunRecord, estimator_options
from softsbi.workflows.fit.report_file import ChamferStats, chamfer_stats
from softsbi.workflows.fit.jobs import JobItem, SimContext, _round_seeds, map_simulations, prior_unit_draws, sensor_parameters
from softsbi.workflows.reporting import FitCallbacks, SimulationIssues
from softsbi.workflows.fit.resume import RunClock, observed_data
from softsbi.workflows.fit.task_store import PriorRound


def _simulate_missing(store: RunStore, r: int, ctx: SimContext, executor: Any, hooks: FitCallbacks,
                      clock: RunClock | None = None, sensor: "SensorDraws | None" = None) -> None:
    """Simulate round ``r``'s pending simulations and store them; those read from the context's simulation bank
    are counted in the round (:meth:`RunStore.add_bank_hits`, also when interrupted) and told to ``hooks``, as are
    the failed ones and those the engine warned about, once, the first few with their parameters
    (:class:`~softsbi.workflows.reporting.SimulationIssues`)."""
    count, n = BankCount(), len(store.pending(r))
    issues = SimulationIssues(ctx.param_names)
    try:
        _simulate_pending(store, r, ctx, executor, hooks, count, clock, sensor, issues)
    finally:
        if count.hits:
            with contextlib.suppress(OSError):
                store.add_bank_hits(r, count.hits)
    tell_bank(hooks, r, count, n, ctx.bank)
    if (line := issues.line(f"round {r + 1}")) is not None:
        hooks.message(line)


def tell_bank(hooks: FitCallbacks, r: int, count: BankCount, n: int, bank: str | None) -> None:
    """Tell ``hooks`` how many of phase ``r``'s ``n`` simulations were read from ``bank``, and warn once of entries
    stored there under another key."""
    if count.hits:
        hooks.read_from_bank(r, count.hits, n)
    if count.wrong_key or count.unstored:
        hooks.message(count.warning(bank))


def _simulate_pending(store: RunStore, r: int, ctx: SimContext, executor: Any, hooks: FitCallbacks,
                      count: BankCount, clock: RunClock | None, sensor: "SensorDraws | None",
                      issues: SimulationIssues) -> None:
    data = store.round_data(r, ROUND_ARRAYS + (("sensor_u",) if sensor is not None else ()))
    extra = "sensor_u" in data
    for attempt in range(2):  # one retry for jobs whose worker crashed
        pending = store.pending(r)
        if len(pending) == 0:
            return
        items = [JobItem(data["theta"][i], int(data["seed"][i]),
                         sensor_draws=sensor.job_draws(data["sensor_u"][i]) if extra else None) for i in pending]
        done = len(data["status"]) - len(pending)
        errors = []
        for j, res in map_simulations(executor, ctx, items):
            i = int(pending[j])
            if isinstance(res, SoftsbiError):
                raise res
            if isinstance(res, WorkerFailure):  # crashed/hung on every attempt the executor allowed
                store.write_simulation(r, i, None, None, STATUS_ERROR, f"{type(res).__name__}: {res}")
                issues.add(data["theta"][i], False, f"{type(res).__name__}: {res}")
                done += 1
                hooks.simulation_done(r, done, len(data["status"]))
                continue
            if isinstance(res, BaseException):
                errors.append(i)
                if attempt == 1:
                    store.write_simulation(r, i, None, None, STATUS_ERROR, f"{type(res).__name__}: {res}")
                    issues.add(data["theta"][i], False, f"{type(res).__name__}: {res}")
                continue
            store.write_simulation(r, i, res.x, res.chamfer, res.status, res.reason, sensor_x=res.sensor_x)
            count.add(res.bank)
            issues.add(data["theta"][i], res.ok, res.reason, res.warning)
            if clock is not None:
                clock.save()
            done += 1
            hooks.simulation_done(r, done, len(data["status"]))
        if not errors:
            return
        hooks.message(f"round {r + 1}: {len(errors)} simulations raised in their worker; retrying them once")


class SensorDraws:
    """``FitConfig.sensor_draws`` of one fit: which parameters are the sensor effects', how to draw them.

    Attributes:
        k: draws per simulation.
        effects: the sensor effects' names, in the fit's order (every observation transform of the fit).
        dims: their inferred parameters' indices in the fit's parameter space.
    """

    def __init__(self, k: int, effects: list[str], dims: list[int], space: ParamSpace):
        self.k, self.effects, self.dims, self.space = k, effects, dims, space

    @classmethod
    def of(cls, cfg: FitConfig, space: ParamSpace, ctx: SimContext, usable: bool) -> "SensorDraws | None":
        """None unless ``cfg.sensor_draws >= 1``, ``usable`` (truncated proposals or a bulk estimator), a
        point-cloud fit with the height sensor model, and every observation transform of ``cfg.effects`` is
        an observation-only effect with an inferred parameter."""
        if cfg.sensor_draws < 1 or not usable or ctx.ref_masks is not None or ctx.camera is not None \
                or getattr(registry().observer(cfg.observer), "needs_images", False):
            return None
        reg, sim = registry(), registry().simulator(cfg.backend)
        names, dims = [], []
        for name in cfg.effects:
            eff = reg.effect(name)()
            doors = set(eff.doors(sim.name))
            if OBSERVATION not in doors:
                continue
            if doors != {OBSERVATION}:
                return None  # an observation transform that also acts on the physics: simulate each time
            names.append(name)
            dims += [space.names.index(p.name) for p in eff.param_space() if p.name in space.names]
        return cls(cfg.sensor_draws, names, dims, space) if dims else None

    def draw(self, u: np.ndarray, proposal: Any, rng: np.random.Generator) -> np.ndarray:
        """``(n, K, D)`` unit-cube draws: each row of ``u (n, D)`` with its sensor dimensions drawn again from
        ``proposal`` given the others (None: the prior, uniform; a
        :class:`~softsbi.core.distributions.TruncatedPrior`: uniform within its region, by rejection; a row
        whose region admits too few after 20 tries keeps its own values for the rest)."""
        out = np.repeat(u[:, None, :], self.k, axis=1)
        for i in range(len(u)):
            got: list[np.ndarray] = []
            for _ in range(20):
                cand = np.repeat(u[i][None], 64 * self.k, axis=0)
                cand[:, self.dims] = rng.random((len(cand), len(self.dims)))
                if proposal is not None:
                    cand = cand[proposal.in_region(cand)]
                got += list(cand[: self.k - len(got)])
                if len(got) >= self.k:
                    break
            if got:
                out[i, : len(got)] = np.array(got)
        return out

    def job_draws(self, sensor_u: np.ndarray) -> dict[str, Any]:
        """The worker's ``sensor_draws`` item (:func:`~softsbi.workflows.fit.jobs.simulate_job`) of one simulation's
        ``(K, D)`` unit-cube draws: their sensor parameters in physical units."""
        names = [self.space.names[d] for d in self.dims]
        return {"effects": list(self.effects),
                "draws": [{n: float(v) for n, v in zip(names, self.space.from_unit(row[None])[0][self.dims])}
                          for row in sensor_u]}


def _sensor_pairs(store: RunStore, upto: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stored ``sensor_draws`` pairs of rounds ``<= upto``: ``(m, D)`` unit-cube parameters, their
    ``(m, T, 1+K, 3)`` observations and ``(m,)`` the index of their simulation among :func:`usable_simulations`'s rows; pairs
    of simulations :func:`usable_simulations` keeps, with finite observations (empty when none)."""
    us, xs, gs = [], [], []
    offset = 0
    for r in range(upto + 1):
        d = store.round_data(r, ("status", "x", "sensor_u", "sensor_x"))
        ok = _usable_rows(d)
        if "sensor_u" in d:
            u, x = d["sensor_u"][ok], d["sensor_x"][ok]  # (n_ok, K, D), (n_ok, K, ...)
            row = np.repeat(offset + np.arange(len(u)), u.shape[1])
            u, x = u.reshape(-1, u.shape[-1]), x.reshape(-1, *x.shape[2:])
            fin = np.all(np.isfinite(x.reshape(len(x), -1)), axis=1)
            us.append(u[fin])
            xs.append(x[fin])
            gs.append(row[fin])
        offset += int(ok.sum())
    if not us:
        return np.zeros((0, 0)), np.zeros((0,)), np.zeros(0, int)
    return np.concatenate(us), np.concatenate(xs), np.concatenate(gs)


def _usable_rows(d: dict[str, np.ndarray]) -> np.ndarray:
    """``(n,)`` bool: the simulations of a round's arrays ``d`` that training uses (status ok, finite state)."""
    x = d["x"]
    return (d["status"] == STATUS_OK) & np.all(np.isfinite(x.reshape(len(x), int(np.prod(x.shape[1:])))), axis=1)


def usable_simulations(store: RunStore, upto: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """The simulations of rounds ``<= upto`` that training uses (status ok, finite state), in round order:
    ``U (n, D)`` their unit-cube parameters, ``X (n, T, 1+K, 3)`` their observations and the number of them per
    round (``upto + 1`` ints). Raises ``KeyError`` for a round that is not stored."""
    us, xs, counts = [], [], []
    for r in range(upto + 1):
        d = store.round_data(r)
        ok = _usable_rows(d)
        us.append(d["u"][ok])
        xs.append(d["x"][ok])
        counts.append(int(ok.sum()))
    return np.concatenate(us), np.concatenate(xs), counts


def start_box_unit(space: ParamSpace, box: Mapping[str, Sequence[float]]) -> tuple[np.ndarray, np.ndarray]:
    """A start box (:attr:`FitConfig.start_box`, ``{name: [low, high]}`` in physical units) as ``(low, high)``,
    each ``(D,)`` in ``space``'s unit cube (clipped to it; a parameter not named spans ``[0, 1]``).

    Raises:
        SoftsbiError: a named parameter is not one of ``space``'s."""
    unknown = sorted(set(box) - set(space.names))
    if unknown:
        raise SoftsbiError(f"start_box names {unknown}, which this fit does not infer (its parameters: "
                           f"{space.names})")
    mid = space.from_unit(np.full((1, space.dim), 0.5))[0]
    ends = np.stack([mid, mid])
    for name, (lo, hi) in box.items():
        ends[:, space.names.index(name)] = (float(lo), float(hi))
    u = np.clip(space.to_unit(ends), 0.0, 1.0)
    low, high = np.zeros(space.dim), np.ones(space.dim)
    for name in box:
        j = space.names.index(name)
        low[j], high[j] = u[:, j].min(), u[:, j].max()
    return low, high


def chain_counts(store: RunStore, counts: list[int]) -> list[int]:
    """The usable simulations per round ``counts`` (:func:`usable_simulations`) as the posterior chain weighs the
    rounds' proposals: a first round that drew nothing (the stored task's posterior alone, ``task_only``) counts the
    prior simulations its task was trained on (its stored training information), at least 1."""
    if counts and counts[0] == 0 and not len(store.round_data(0, ("status",))["status"]):
        counts = [max(store.round_record(0).n_train_total, 1), *counts[1:]]
    return counts


class Rounds:
    """The sequential rounds of one fit: draw the proposal, simulate, train, condition."""

    def __init__(self, cfg: FitConfig, store: RunStore, space: ParamSpace, ctx: SimContext, est_cls: type,
                 callbacks: FitCallbacks, clock: RunClock | None = None, prior: PriorRound | None = None,
                 task_only: bool = False):
        self.cfg, self.store, self.space, self.ctx, self.est_cls, self.cb = cfg, store, space, ctx, est_cls, callbacks
        self.clock = clock
        self.prior = prior or PriorRound(None, None)  # the first round as a stored task (:mod:`.tasks`)
        #: a first round begun here draws nothing: its posterior is the stored task's alone (its prior
        #: simulations are neither read from the bank nor scored: :func:`~softsbi.workflows.fit.run.run_fit`)
        self.task_only = task_only
        self.sequential = bool(getattr(est_cls, "sequential", True))
        self.truncated = self.sequential and cfg.proposal == "truncated"
        self.chain = PosteriorChain(space.dim, seed=cfg.seed)
        self.summaries: list[dict[str, Any]] = []
        self.prior_stats = ChamferStats()
        self.x_obs = store.read_observed()["x"]
        self.scored = ctx.dense is not None or ctx.ref_masks is not None
        self.sensor = SensorDraws.of(cfg, space, ctx, self.truncated or not self.sequential)

    def run_round(self, r: int, executor: Any) -> None:
        """Round ``r``: begin it (draw and store its parameters) unless stored, simulate what is
        pending, train the estimator unless the round is complete, add its posterior."""
        cfg, store = self.cfg, self.store
        if not store.is_begun(r):
            self._begin(r)
        self.cb.round_start(r, cfg.rounds, len(store.pending(r)), cfg.sims_per_round)
        bank = bank_folder(cfg.sim_bank) if r == 0 else None  # the first round's draws depend on the task and the seed alone
        ctx = self.ctx if bank is None else replace(self.ctx, bank=str(bank))
        _simulate_missing(store, r, ctx, executor, self.cb, self.clock, self.sensor)
        d = store.round_data(r)
        frames = RunRecord.from_run_config(store.config).metric_frames
        stats = chamfer_stats(d["chamfer"], d["status"], frames) if self.scored else ChamferStats()
        if r == 0:
            self.prior_stats = stats
        elif self.summaries:
            self.summaries[-1]["chamfer_posterior"] = stats  # round r draws from posterior r-1
        U, X, counts = usable_simulations(store, r)
        if r == 0 and not len(d["status"]):  # a first round that drew nothing: the stored task's posterior alone
            if not (store.is_complete(r) or self.prior.usable(0)):
                raise SoftsbiError(f"round 1 of {store.path} drew no simulations of its own: its posterior is a "
                                   f"stored task's, which is no longer stored; fit into a new --out folder")
        elif counts[r] == 0:
            reasons = sorted(set(store.round_record(r).failures.values()))
            effect_code = all(x.startswith(EffectFault.__name__) for x in reasons)  # an effect's code, not physics
            raise SoftsbiError(f"round {r + 1}: every simulation failed, e.g. {reasons[:3]}; "
                               + ("fix the effect's code named there" if effect_code else
                                  "narrow the prior bounds with --bounds or change backend options")
                               + f"; if the environment made them "
                               f"fail, fix it and re-run with --retry-failed (finished simulations are kept in "
                               f"{store.path})")
        q, info = self._train(r, U, X, counts)
        post = self._add_posterior(r, q, chain_counts(store, counts))
        try:
            mean_u, _ = post.moments(4000, seed=cfg.seed + r)
        except PosteriorError as exc:
            raise PosteriorError(f"round {r + 1}: estimator '{cfg.estimator}' conditioned on the measurement: {exc}. "
                                 f"Try another estimator (e.g. rkhs), more --sims-per-round or wider --bounds; "
                                 f"the finished simulations are kept in {store.path}") from exc
        self.summaries.append({"round": r, "simulations": int(len(d["status"])), "usable": counts[r],
                               "failed": int((d["status"] != STATUS_OK).sum()),
                               "bank_hits": int(store.round_record(r).bank_hits),
                               "chamfer_proposal": stats, "train": info, "mass_in_box": post.mass_in_box,
                               "posterior_mean": self.space.as_dict(self.space.from_unit(mean_u))})
        self.cb.round_end(r, self.summaries[-1])

    def _begin(self, r: int) -> None:
        """Draw round ``r``'s parameters from its proposal and store them (with their seeds); a first round that
        is the stored task's alone (``task_only``) draws none."""
        cfg, space = self.cfg, self.space
        if r == 0 and self.task_only:
            none = np.zeros((0, space.dim))
            self.store.begin_round(r, none, none, np.zeros(0, np.int64), self.x_obs.shape,
                                   f"none: stored task {self.prior.digest}'s posterior, conditioned on the recording")
            return
        proposal = None  # bulk estimators (sequential = False): every round draws from the prior
        if r > 0 and self.sequential:
            proposal = self.chain.posterior(len(self.chain) - 1)
            if self.truncated:
                proposal = TruncatedPrior(proposal, eps=cfg.truncation_eps, seed=cfg.seed + r)
        rng = np.random.default_rng([cfg.seed, r, 0])
        # from the prior: a sensor effect's parameters from a stream of their own, so that its cloth parameters and
        # rollouts are the model's without it (read from the bank)
        u = prior_unit_draws([cfg.seed, r, 0], cfg.sims_per_round, space.names,
                             sensor_parameters(cfg.backend, cfg.effects)) if proposal is None else \
            proposal.sample(cfg.sims_per_round, rng)
        if r == 0 and cfg.start_box:  # the prior restricted to a box (FitConfig.start_box): a truncated proposal
            low, high = start_box_unit(space, cfg.start_box)
            u = low + (high - low) * u
            self.store.begin_round(r, space.from_unit(u), u, _round_seeds(cfg.seed, r, cfg.sims_per_round),
                                   self.x_obs.shape, f"prior restricted to the start box of "
                                   f"{', '.join(sorted(cfg.start_box))} (prior mass {np.prod(high - low):.3g})")
            return
        what = "prior" if proposal is None else (
            f"prior truncated to the {1 - cfg.truncation_eps:g} region of round {r}'s posterior "
            f"(prior mass {proposal.prior_mass:.3g})" if self.truncated else f"posterior of round {r}")
        sensor_u = (self.sensor.draw(u, proposal, np.random.default_rng([cfg.seed, r, 1]))
                    if self.sensor is not None else None)
        self.store.begin_round(r, space.from_unit(u), u, _round_seeds(cfg.seed, r, cfg.sims_per_round),
                               self.x_obs.shape, what, sensor_u=sensor_u)

    def _train(self, r: int, U: np.ndarray, X: np.ndarray, counts: list[int]) -> tuple[Any, dict[str, Any]]:
        """The posterior at the observation after round ``r`` (stored once trained)."""
        cfg, store = self.cfg, self.store
        if store.is_complete(r):
            try:
                return round_posterior(store, r, cfg), store.round_record(r).info
            except PosteriorDamaged as exc:  # train the round again from its intact simulations
                self.cb.message(f"{exc.problem}: training that round again from its stored simulations")
        opts = estimator_options(cfg, self.est_cls)
        fr = slice(None) if cfg.frames is None else list(cfg.frames)
        n_drawn = len(store.round_data(r, ("status",))["status"])
        task = self.prior.task
        if r == 0 and self.prior.usable(n_drawn):
            # trained once for this task, on prior draws whose first n_drawn are this round's: condition only
            q = task.restore().posterior_at(self.x_obs[fr])
            self.cb.message(f"round 1: the stored task {task.digest[:12]} (trained once on {task.n_prior} prior "
                            f"simulations): conditioned on this recording, no training")
            info = dict(task.info, task=task.digest, trained_here=False)
            store.finish_round(r, q, info, estimator=None if isinstance(q, MixtureOfGaussians) else task.estimator)
            return q, info
        if r == 0 and task is not None:
            self.cb.message(f"round 1: the stored task {task.digest[:12]} was trained on {task.n_prior} prior "
                            f"simulations, fewer than this round's {n_drawn}: not used, the round is trained here "
                            f"(--sims-per-round {task.n_prior} or fewer uses it; `softsbi task train --prior-sims "
                            f"{n_drawn}` trains it for more)")
        est = self.est_cls(**opts)
        n_sensor, kw = 0, {}
        if self.sensor is not None:  # one simulation, K more observations at other sensor parameters
            su, sx, sg = _sensor_pairs(store, r)
            n_sensor = len(su)
            if n_sensor:
                U, X = np.concatenate([U, su]), np.concatenate([X, sx])
                if "groups" in inspect.signature(est.fit).parameters:  # hold out whole simulations
                    kw["groups"] = np.concatenate([np.arange(len(U) - n_sensor), sg])
        info = est.fit(U.astype(np.float64), X[:, fr].astype(np.float64), seed=cfg.seed + r,
                       progress=lambda e, m, v, _r=r: self.cb.training_epoch(_r, e, m, v), **kw)
        q = est.posterior_at(self.x_obs[fr])  # the posterior at the observation x_o
        info = dict(info, n_train_total=int(len(U)), usable_per_round=counts, sensor_pairs=n_sensor,
                    **({"held_out_by_simulation": "groups" in kw} if n_sensor else {}))
        if r == 0 and self.prior.keep(n_drawn, est, info, opts, cfg.estimator) is not None:
            info = dict(info, task=self.prior.digest, trained_here=True)
            self.cb.message(f"round 1's estimator stored as task {self.prior.digest[:12]}: later recordings of this "
                            f"task condition it instead of training it (`softsbi task list`)")
        state = None if isinstance(q, MixtureOfGaussians) else EstimatorState(cfg.estimator, opts, est.state_dict())
        store.finish_round(r, q, info, estimator=state)
        return q, info

    def _add_posterior(self, r: int, q: Any, counts: list[int]) -> RoundPosterior:
        if self.sequential and not self.truncated:
            return self.chain.add_round(q, counts[r])
        # bulk (all data from the prior) or truncated proposals (TSNPE): the posterior is q
        # restricted to the prior box, with no importance weights
        self.chain = PosteriorChain(self.space.dim, seed=self.cfg.seed)
        return self.chain.add_round(q, sum(counts))


def round_posterior(store: RunStore, r: int, cfg: FitConfig) -> Any:
    """Round ``r``'s posterior ``q(u | x_obs)`` as the fit stored it (unit cube): the Gaussian mixture, or
    the estimator restored from its stored state through the plugin registry (by name and options) and
    conditioned on the run's observation at the fit's frames (``cfg``: the run's settings,
    :meth:`FitConfig.from_run_config`).

    Raises:
        PosteriorDamaged: the stored posterior is missing or damaged (:meth:`RunStore.read_posterior`).
        PluginNotFound: the estimator that wrote it is not installed. DependencyMissing: its optional
            dependency is not.
    """
    stored = store.read_posterior(r)
    if isinstance(stored, MixtureOfGaussians):
        return stored
    est = registry().estimator(stored.name)(**stored.options)
    est.load_state_dict(stored.state)
    fr = slice(None) if cfg.frames is None else list(cfg.frames)
    return est.posterior_at(observed_data(store)["x"][fr])
