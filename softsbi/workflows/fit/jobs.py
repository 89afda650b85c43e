"""The one worker-side job of every workflow: simulate, observe, score.

Fit rounds, the fit's evaluation, ``check``, ``diagnose``, ``view`` and ``calibrate`` all run
:func:`simulate_job` through an executor, so a rollout at the same parameters and seed gives the
same observation and the same Chamfer everywhere.
"""
from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from softsbi.backends.common import check_effects
from softsbi.core.errors import EnvironmentFault, SoftsbiError
from softsbi.core.interfaces import OBSERVATION
from softsbi.core.types import (INFO_ARM_MASK_RADIUS, INFO_ENGINE_WARNINGS, INFO_MIN_VISIBLE_Z, STATUS_ERROR, STATUS_OK,
                                Scenario)
from softsbi.core.seeds import eval_stream
from softsbi.perception.depth_sensor import camera_chamfer_per_frame, sensor_from_json
from softsbi.perception.masks import hsv_mask, mask_chamfer_per_frame
from softsbi.perception.pointcloud import (combined_min_z, effect_views, rollout_arm_radius, rollout_clouds,
                                           rollout_min_z, sensor_chamfer_per_frame)
from softsbi.plugins import registry
from softsbi.workflows.fit.bank import MISS, UNSTORED, BankCount, SimulationBank, rollout_key
from softsbi.workflows import pools
from softsbi.workflows.reporting import SimulationIssues, notify, phase


@dataclass
class SimContext:
    """Read-only data every simulation job needs (shipped once per worker)."""

    backend: str
    backend_options: dict[str, Any]
    scenario: dict[str, Any]
    effects: list[str]
    observer: str
    observer_options: dict[str, Any]
    param_names: list[str]
    fixed: dict[str, float]
    dense: np.ndarray | None
    n_dense: int
    #: ``(T, H, W)`` bool cloth masks of the observed frames: the metric becomes the mask Chamfer (px)
    ref_masks: np.ndarray | None = None
    #: also return the rollout's ``vertices (T, N, 3)``, ``faces (F, 3)`` and ``gripper (T, 3)``
    #: (posterior predictive checks localise the error on the object)
    keep_rollout: bool = False
    #: the fit's sensor model for the metric: simulated and measured points at or below this height
    #: (m, absolute; ``table_z + min_height``) are not seen (:func:`~softsbi.perception.pointcloud.sensor_view`);
    #: None = full clouds
    min_z: float | None = None
    #: the fit's virtual depth sensor for the metric (``VirtualDepthSensor.to_json``), None = height cut
    camera: dict[str, Any] | None = None
    #: a simulation bank (:class:`~softsbi.workflows.fit.bank.SimulationBank` folder) whose stored rollouts are
    #: read instead of simulated, and which keeps the new ones; None = simulate everything
    bank: str | None = None
    #: the summaries of a rollout, computed in the worker for every item with a ``summary_seed``
    #: (``summarise(result, summary_seed) -> (F,)``, a picklable callable such as a ``functools.partial`` of a
    #: module-level function; the criticism's posterior-predictive summaries); None = none. The result it is given
    #: holds the rollout (``vertices``, ``faces``, ``gripper``, ``min_visible_z``) whatever ``keep_rollout`` says
    summarise: Any = None


@dataclass(frozen=True)
class JobItem:
    """One simulation for :func:`simulate_job`.

    Attributes:
        theta: ``(D,)`` in the order of ``SimContext.param_names`` (physical units), or a ``{name: value}`` mapping;
            ``SimContext.fixed`` is added to it.
        seed: the simulation's seed.
        effects: effect names that replace ``SimContext.effects`` for this simulation (None = the context's; the
            diagnosis's sensitivity simulations switch candidate effects on one at a time).
        sensor_draws: ``{"effects": names, "draws": [{param: value}, ...]}``: the named effects (observation
            transforms only, every observation transform of the effects, in their order) are applied after the
            simulation, once with ``theta`` (the result's ``x`` and Chamfer, the same numbers as without
            ``sensor_draws``) and once per draw, whose parameters replace ``theta``'s: one simulation, several
            observations (``FitConfig.sensor_draws``). None = one observation.
        summary_seed: the seed of the rollout's summaries, computed in the worker by ``SimContext.summarise``
            (the result's ``features``); None = no summaries.
    """

    theta: np.ndarray | Mapping[str, float]
    seed: int
    effects: Sequence[str] | None = field(default=None, kw_only=True)
    sensor_draws: Mapping[str, Any] | None = field(default=None, kw_only=True)
    summary_seed: int | None = field(default=None, kw_only=True)


@dataclass(frozen=True, kw_only=True, eq=False)
class JobResult:
    """What :func:`simulate_job` returns for one :class:`JobItem` (also a failed job's result, made by
    :func:`run_jobs` or a round for a crashed worker: its ``status`` and ``reason`` only).

    Attributes:
        status: :data:`~softsbi.core.types.STATUS_OK`, or the failure's status. reason: why it failed ("" if ok).
        x: ``(T, 1+K, 3)`` the observation, None when it failed.
        chamfer: ``(T,)`` the fit's metric per frame: the bidirectional 3-D Chamfer (m) against
            ``SimContext.dense``, both clouds seen through the sensor model, or the mask Chamfer (px) of an image fit;
            None when it failed or the context has no measurement.
        chamfer_one_sided: ``(T,)`` its measured -> simulated half (m), None for image fits.
        seconds: the job's wall time (s), None for a result not made by the job.
        bank: what the simulation bank found (:data:`~softsbi.workflows.fit.bank.HIT`, ``MISS``, ``WRONG_KEY``,
            ``UNSTORED``; None without one).
        sensor_x: ``(K, T, 1+K, 3)`` the observations at the item's K sensor draws (None without ``sensor_draws``).
        vertices: ``(T, N, 3)`` m, faces: ``(F, 3)``, gripper: ``(T, 3)`` m: the rollout, with
            ``SimContext.keep_rollout`` only.
        min_visible_z: a sensor effect's visibility threshold (m, absolute) on the rollout
            (:data:`~softsbi.core.types.INFO_MIN_VISIBLE_Z`), with ``keep_rollout`` only; None = none.
        arm_mask_radius: a sensor effect's arm-mask radius (m) on the rollout
            (:data:`~softsbi.core.types.INFO_ARM_MASK_RADIUS`), with ``keep_rollout`` only; None = none.
        seed: the item's seed. sample: the posterior sample the rollout simulates, set by the consumers that pair
            results with samples (:meth:`~softsbi.workflows.fit.runs.RunView.posterior_rollouts`); None otherwise.
        features: ``(F,)`` the rollout's summaries (``SimContext.summarise`` with the item's ``summary_seed``),
            None without them.
        warning: the engine's warnings during the rollout (:data:`~softsbi.core.types.INFO_ENGINE_WARNINGS`), ``""``
            when none.
    """

    status: int
    reason: str = ""
    x: np.ndarray | None = None
    chamfer: np.ndarray | None = None
    chamfer_one_sided: np.ndarray | None = None
    seconds: float | None = None
    bank: str | None = None
    sensor_x: np.ndarray | None = None
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    gripper: np.ndarray | None = None
    min_visible_z: float | None = None
    arm_mask_radius: float | None = None
    seed: int | None = None
    sample: int | None = None
    features: np.ndarray | None = None
    warning: str = ""

    @property
    def ok(self) -> bool:
        """Whether the simulation succeeded (``status == STATUS_OK``)."""
        return self.status == STATUS_OK

    @property
    def info(self) -> dict[str, float]:
        """The rollout's sensor information as a rollout carries it (``{INFO_MIN_VISIBLE_Z: m, INFO_ARM_MASK_RADIUS:
        m}``, each only when set), for :func:`~softsbi.perception.pointcloud.rollout_min_z` and
        :func:`~softsbi.perception.pointcloud.effect_views`."""
        out = {} if self.min_visible_z is None else {INFO_MIN_VISIBLE_Z: self.min_visible_z}
        if self.arm_mask_radius is not None:
            out[INFO_ARM_MASK_RADIUS] = self.arm_mask_radius
        return out


def failed(exc: BaseException) -> JobResult:
    """The result of a job that raised ``exc`` in its worker or whose worker crashed: ``STATUS_ERROR`` and
    ``"Type: message"``."""
    return JobResult(status=STATUS_ERROR, reason=f"{type(exc).__name__}: {exc}")


_WORKER_CACHE: dict[str, Any] = {}


def _objects(ctx: SimContext) -> tuple[Any, Any, Scenario]:
    key = json.dumps([ctx.backend, ctx.backend_options, ctx.observer, ctx.observer_options, ctx.scenario],
                     sort_keys=True, default=str)
    if key not in _WORKER_CACHE:
        reg = registry()
        sim = reg.simulator(ctx.backend)(**ctx.backend_options)
        obs = reg.observer(ctx.observer)(**ctx.observer_options)
        _WORKER_CACHE.clear()
        _WORKER_CACHE[key] = (sim, obs, Scenario.from_json(ctx.scenario))
    return _WORKER_CACHE[key]


class _Deferred(BaseException):
    """A simulation left for its batch's ``simulate_batch`` call (:class:`_Batch`, first pass). A BaseException, so
    that the job's engine-error handler does not take it for a failed simulation."""


class _Batch:
    """The rollouts of one batch of jobs (:func:`simulate_batch_job`).

    The jobs run twice. In the first pass each rollout a job asks for is recorded and the job stops
    (:class:`_Deferred`); :meth:`run` then rolls the recorded ones out with one ``simulate_batch`` call per effect
    set; in the second pass every job runs to its end on them. A job that needs no new rollout (a bank hit) ends in
    the first pass.
    """

    def __init__(self, sim: Any):
        self.sim = sim
        self._pending: dict[tuple, tuple] = {}
        self._done: dict[tuple, Any] = {}

    def simulate(self, scenario: Scenario, values: dict[str, float], effects: list[str], seed: int) -> Any:
        key = (tuple(sorted(values.items())), tuple(effects), int(seed))
        if key in self._done:
            got = self._done[key]
            if isinstance(got, Exception):
                raise got
            return got
        self._pending[key] = (scenario, values, list(effects), int(seed))
        raise _Deferred

    def run(self) -> None:
        """Roll the recorded simulations out, one ``simulate_batch`` per effect set. When a batch call raises (one
        theta outside the physical limits fails all of it), its simulations run one by one, so each keeps its own
        outcome: a rollout, or the exception its job raises or reports as the single simulation would."""
        groups: dict[tuple, list[tuple]] = {}
        for key, req in self._pending.items():
            groups.setdefault(key[1], []).append((key, req))
        for effects, reqs in groups.items():
            try:
                ros = self.sim.simulate_batch(reqs[0][1][0], [r[1] for _, r in reqs], list(effects),
                                              [r[3] for _, r in reqs])
                self._done.update((key, ro) for (key, _), ro in zip(reqs, ros, strict=True))
            except Exception:  # noqa: BLE001 - told per simulation below
                for key, (scenario, values, eff, seed) in reqs:
                    try:
                        self._done[key] = self.sim.simulate(scenario, values, effects=eff, seed=seed)
                    except Exception as exc:  # noqa: BLE001 - raised in its job's second pass
                        self._done[key] = exc
        self._pending.clear()


def _rollout(sim: Any, scenario: Scenario, values: dict[str, float], effects: list[str], seed: int,
             batch: _Batch | None) -> Any:
    if batch is None:
        return sim.simulate(scenario, values, effects=effects, seed=seed)
    return batch.simulate(scenario, values, effects, seed)


def _simulate(ctx: SimContext, sim: Any, scenario: Scenario, values: dict[str, float], effects: list[str],
              seed: int, batch: _Batch | None = None) -> tuple[Any, str | None]:
    """``(rollout, what the bank found)``: ``sim.simulate`` (or the job's ``batch``), through the context's
    simulation bank when it has one (:meth:`~softsbi.workflows.fit.bank.SimulationBank.lookup`; None without a bank)."""
    if ctx.bank is None:
        return _rollout(sim, scenario, values, effects, seed, batch), None
    bank = SimulationBank(ctx.bank)
    key = rollout_key(ctx.backend, ctx.backend_options, ctx.scenario, effects, values, seed)
    ro, what = bank.lookup(key)
    if ro is None:
        ro = _rollout(sim, scenario, values, effects, seed, batch)
        if not bank.put(key, ro) and what == MISS and ro.ok and ro.rgb is None:
            what = UNSTORED  # a full or read-only disk: told once per phase (BankCount.warning)
    return ro, what


def _simulate_observed(ctx: SimContext, sim: Any, scenario: Scenario, values: dict[str, float], effects: list[str],
                       seed: int, batch: _Batch | None = None) -> tuple[Any, str | None]:
    """:func:`_simulate` with ``effects``; with a bank, the observation-only effects (sensor effects: every door of
    theirs is an observation transform) are applied after the banked rollout of the others, which does not depend on
    them, so a model with a sensor effect reads the nominal model's rollouts. The same numbers as simulating with
    every effect: the backends apply the observation transforms last, in order, seeded by ``seed``."""
    if ctx.bank is None or not effects:
        return _simulate(ctx, sim, scenario, values, effects, seed, batch)
    plan = check_effects(sim, effects)
    sensor = sensor_effects(sim, plan)
    if not sensor or len(sensor) != len(plan.observers):  # none, or mixed with a physical one's: keep the order
        return _simulate(ctx, sim, scenario, values, effects, seed, batch)
    raw, banked = _simulate_unobserved(ctx, sim, scenario, values, effects, sensor, seed, batch)
    return plan.observe(raw, values, seed), banked  # its observation transforms are exactly the sensor effects'


def sensor_effects(sim: Any, plan: Any) -> list[Any]:
    """The observation-only (sensor) effects of ``plan`` (:func:`~softsbi.backends.common.check_effects` on ``sim``):
    every door of theirs is an observation transform, so a rollout does not depend on them."""
    return [e for e in plan.observers if set(e.doors(sim.name)) == {OBSERVATION}]


def sensor_parameters(backend: str, effects: Sequence[str]) -> set[str]:
    """The parameters of ``effects``' sensor effects on ``backend`` (:func:`sensor_effects`): those a rollout does not
    depend on (:func:`_simulate_observed` applies their transforms after the banked rollout of the others)."""
    if not effects:
        return set()
    sim = registry().simulator(backend)()
    return {p.name for e in sensor_effects(sim, check_effects(sim, list(effects))) for p in e.param_space()}


def prior_unit_draws(seed: Sequence[int], n: int, names: Sequence[str], sensor: set[str] = frozenset()) -> np.ndarray:
    """``(n, D)`` uniform draws in the unit cube for the parameters ``names``: the others than ``sensor``
    (:func:`sensor_parameters`) from the stream ``seed``, row by row exactly as ``default_rng(seed).random((n, d))``,
    and ``sensor``'s from a stream of their own (``[*seed, 1]``). So a model with a sensor effect draws the very
    cloth parameters of the model without it, at the same simulation seeds, and its rollouts are that model's (read
    from the simulation bank: a trained task's sensor models then simulate nothing)."""
    own = [j for j, name in enumerate(names) if name in sensor]
    rest = [j for j in range(len(names)) if j not in own]
    u = np.empty((n, len(names)))
    u[:, rest] = np.random.default_rng(list(seed)).random((n, len(rest)))
    if own:
        u[:, own] = np.random.default_rng([*seed, 1]).random((n, len(own)))
    return u


def _simulate_unobserved(ctx: SimContext, sim: Any, scenario: Scenario, values: dict[str, float], effects: list[str],
                         sensor: list[Any], seed: int, batch: _Batch | None = None) -> tuple[Any, str | None]:
    """:func:`_simulate` without the observation-only effects ``sensor`` (effect instances) and their parameters,
    which the rollout does not depend on: the raw rollout their transforms are applied to afterwards."""
    own = {p.name for e in sensor for p in e.param_space()}
    names = {e.name for e in sensor}
    return _simulate(ctx, sim, scenario, {k: v for k, v in values.items() if k not in own},
                     [e for e in effects if e not in names], seed, batch)


def failure_reason(exc: Exception, backend: str) -> str:
    """The stored reason of a simulation that raised ``exc``: ``"Type: message"`` (an engine's error, or a plugin's
    fault such as an :class:`~softsbi.core.errors.EffectFault` or a scenario the backend cannot build), a failed
    simulation with which the command goes on.

    Raises:
        SoftsbiError: ``exc`` itself, when it is one (a deliberate error stops the command).
        EnvironmentFault: ``exc`` is an ImportError or OSError: the machine cannot simulate at all (nothing is
            stored as failed; the same command resumes once it is fixed).
    """
    if isinstance(exc, SoftsbiError):
        raise exc
    if isinstance(exc, (ImportError, OSError)):
        raise EnvironmentFault(f"{backend} cannot simulate on this machine ({type(exc).__name__}: {exc}); "
                               f"fix the installation and re-run the same command to resume") from exc
    return f"{type(exc).__name__}: {exc}"


def simulate_job(ctx: SimContext, item: JobItem, batch: _Batch | None = None) -> JobResult:
    """Simulate one parameter vector, observe it and score it against the measurement.

    Args:
        ctx: the shared context.
        item: the simulation (:class:`JobItem`): ``theta``, ``seed``, and optionally the effects that replace
            ``ctx.effects`` and the sensor draws observed besides ``theta``.
        batch: (:func:`simulate_batch_job` only) takes the rollouts the job asks for.

    Returns:
        A :class:`JobResult`: ``status``, ``reason``, ``x``, ``chamfer``, ``chamfer_one_sided``, ``seconds``,
        ``bank`` and ``seed``; ``sensor_x`` with ``item.sensor_draws``; ``vertices``, ``faces``, ``gripper``,
        ``min_visible_z`` and ``arm_mask_radius`` when ``ctx.keep_rollout``. ``chamfer`` is the bidirectional 3-D
        Chamfer (m) per frame against ``ctx.dense``, both clouds seen through the sensor model ``ctx.min_z`` (the
        simulated one also through the rollout's sensor effects: table-unseen's height, the arm's mask), and
        ``chamfer_one_sided`` its measured -> simulated half
        (:func:`~softsbi.perception.pointcloud.sensor_chamfer_per_frame`); for image fits ``chamfer`` is the mask
        Chamfer (px) against ``ctx.ref_masks`` and ``chamfer_one_sided`` None. A failed simulation has its status and
        reason only.
    """

    theta, seed = item.theta, int(item.seed)
    effects = list(item.effects) if item.effects is not None else list(ctx.effects)
    draws = item.sensor_draws
    t0 = time.perf_counter()
    sim, obs, scenario = _objects(ctx)
    if isinstance(theta, Mapping):
        values = {k: float(v) for k, v in theta.items()}
    else:
        values = dict(zip(ctx.param_names, map(float, theta)))
    values.update(ctx.fixed)
    banked = None
    try:
        if getattr(obs, "needs_images", False):
            ro = sim.simulate_images(scenario, values, camera=obs.camera, effects=effects, seed=seed,
                                     style=obs.style)
        elif draws:  # simulate without the observation transforms, then observe once per draw
            plan = check_effects(sim, draws["effects"])
            raw, banked = _simulate_unobserved(ctx, sim, scenario, values, effects, plan.effects, seed, batch)
            ro = plan.observe(raw, values, seed)
        else:
            ro, banked = _simulate_observed(ctx, sim, scenario, values, effects, seed, batch)
    except Exception as exc:  # noqa: BLE001 - an engine error is a failed simulation
        return JobResult(status=STATUS_ERROR, reason=failure_reason(exc, ctx.backend),
                         seconds=time.perf_counter() - t0, bank=banked, seed=seed)
    warning = str(ro.info.get(INFO_ENGINE_WARNINGS, ""))
    if not ro.ok:
        return JobResult(status=int(ro.status), reason=ro.reason, seconds=time.perf_counter() - t0, bank=banked,
                         seed=seed, warning=warning)
    rng = np.random.default_rng([seed, 17])
    effect_z = rollout_min_z(ro)  # a sensor effect's visibility threshold (table-unseen), else None
    # a camera fit: the virtual depth sensor makes the simulated clouds of the metric (FitConfig.sensor) and
    # of the point-cloud observer (the same per-process sensor, sensor_from_json); each frame is rendered once
    # and shared by both (same rng draws, so the same numbers as rendering twice)
    sensor = sensor_from_json(ctx.camera) if ctx.camera is not None and ctx.ref_masks is None else None
    with sensor.shared_renders() if sensor is not None else nullcontext():
        o = obs.observe(ro, rng)
        x = o.state()
        ch = ch1 = None
        if ctx.ref_masks is not None:
            ch = mask_chamfer_per_frame(hsv_mask(ro.rgb), ctx.ref_masks)
        elif ctx.dense is not None:
            surface = rollout_clouds(ro, ctx.n_dense, rng)
            if sensor is not None:
                ch, ch1 = camera_chamfer_per_frame(sensor, ro.vertices, ro.faces, ro.gripper, ctx.dense, surface,
                                                   rng)
            else:  # a sensor effect's threshold (table-unseen) adds to the fit's own, its arm mask hides more
                ch, ch1 = sensor_chamfer_per_frame(effect_views(surface, ro), ctx.dense,
                                                   combined_min_z(ctx.min_z, effect_z))
    seconds = time.perf_counter() - t0
    sensor_x = None
    if draws:
        # each draw: the sensor effects' own randomness (point noise) drawn afresh, the observer's point
        # sampling the primary's (so a draw at theta's own sensor parameters repeats x when they are deterministic)
        sensor_x = np.stack([
            obs.observe(plan.observe(raw, {**values, **{k: float(v) for k, v in d.items()}},
                                     seed + 1_000_003 * (j + 1)),
                        np.random.default_rng([seed, 17])).state()
            for j, d in enumerate(draws["draws"])])
    rollout = {"vertices": ro.vertices, "faces": ro.faces, "gripper": ro.gripper, "min_visible_z": effect_z,
               "arm_mask_radius": rollout_arm_radius(ro)}
    res = JobResult(status=STATUS_OK, reason="", x=x, chamfer=ch, chamfer_one_sided=ch1, seconds=seconds,
                    bank=banked, sensor_x=sensor_x, seed=seed, warning=warning, **rollout)
    if ctx.summarise is not None and item.summary_seed is not None:  # in the worker: the main process only reads
        res = replace(res, features=np.asarray(ctx.summarise(res, int(item.summary_seed)), float))
    return res if ctx.keep_rollout else replace(res, vertices=None, faces=None, gripper=None, min_visible_z=None,
                                                arm_mask_radius=None)


def _round_seeds(seed: int, r: int, n: int) -> np.ndarray:
    return np.random.default_rng([seed, r, 1]).integers(0, 2**31 - 1, size=n)


def evaluation_seeds(seed: int, rounds: int, n_eval: int) -> np.ndarray:
    """``(n_eval,)`` simulation seeds of a fit's final evaluation rollouts (posterior predictive):
    a check that re-simulates the same samples with them reproduces the fit's Chamfer exactly."""
    return _round_seeds(seed, eval_stream(rounds), n_eval)


def stored_evaluation_seeds(seed: int, attrs: Mapping[str, Any], rounds: int | None, n_eval: int) -> np.ndarray:
    """:func:`evaluation_seeds` of a stored evaluation (``attrs``: its group's attributes): after the rounds stored with
    it, or ``rounds`` for a run stored before they were kept."""
    return evaluation_seeds(seed, int(attrs.get("rounds", rounds)), n_eval)



def simulate_batch_job(ctx: SimContext, items: Sequence[JobItem]) -> list[JobResult]:
    """:func:`simulate_job` over ``items``, with every rollout they need simulated by the backend's
    ``simulate_batch`` (:class:`_Batch`): the same results, in item order, as one job per item.

    Raises:
        The first :class:`SoftsbiError` an item raises, as :func:`simulate_job` would.
    """
    sim, _, _ = _objects(ctx)
    batch = _Batch(sim)
    out: list[JobResult | None] = [None] * len(items)
    for _ in range(2):
        for i, item in enumerate(items):
            if out[i] is None:
                try:
                    out[i] = simulate_job(ctx, item, batch)
                except _Deferred:
                    pass
        batch.run()
    return out  # type: ignore[return-value]


def batch_size(ctx: SimContext, n: int, workers: int | None) -> int:
    """How many of ``n`` simulations one job runs: the backend's ``batch_size`` (1 for a backend that simulates
    one at a time; :attr:`~softsbi.core.interfaces.Simulator.batch_size`), at most an equal share of ``n`` per worker
    (``workers``; None = one per core), so that every worker gets a batch."""
    try:
        size = int(getattr(registry().simulator(ctx.backend)(**ctx.backend_options), "batch_size", 1))
    except Exception:  # noqa: BLE001 - bad options fail in the workers, one result per simulation, as unbatched
        return 1
    return max(1, min(size, math.ceil(n / max(1, workers or os.cpu_count() or 1))))


def map_simulations(executor: Any, ctx: SimContext, items: Sequence[JobItem]) -> Iterator[tuple[int, Any]]:
    """``executor.map_unordered(simulate_job, items, context=ctx)``: yield ``(index, result or exception)`` in
    completion order. A backend that steps several parameter sets together (``batch_size > 1``, newton-cloth) gets
    them in jobs of :func:`batch_size` items (:func:`simulate_batch_job`); a batch's items are yielded together when
    it ends. A batch that fails as a whole (its worker crashed or hung, or it raised other than a
    :class:`SoftsbiError`, which every item of it is yielded with) has its items run again one per job, so each keeps
    its own outcome: one crashing simulation fails itself only, as unbatched."""
    size = batch_size(ctx, len(items), getattr(executor, "workers", None)) if len(items) > 1 else 1
    if size == 1:
        yield from executor.map_unordered(simulate_job, items, context=ctx)
        return
    starts = range(0, len(items), size)
    chunks = [list(items[s:s + size]) for s in starts]
    alone: list[int] = []  # the items of failed batches, by index
    for c, res in executor.map_unordered(simulate_batch_job, chunks, context=ctx):
        if isinstance(res, BaseException) and not isinstance(res, SoftsbiError):
            alone.extend(range(starts[c], starts[c] + len(chunks[c])))
            continue
        for j in range(len(chunks[c])):
            yield starts[c] + j, res if isinstance(res, BaseException) else res[j]
    if alone:
        for k, res in executor.map_unordered(simulate_job, [items[i] for i in alone], context=ctx):
            yield alone[k], res


def run_jobs(ctx: SimContext, items: Sequence[JobItem], workers: int | None = None, executor: str = "local",
             executor_options: Mapping[str, Any] | None = None, label: str = "simulations",
             contained: tuple[type[BaseException], ...] = ()) -> list[JobResult]:
    """Run :func:`simulate_job` over ``items`` on an executor plugin; results in item order. The phase is told to
    the current progress reporter as ``label`` (:mod:`~softsbi.workflows.reporting`).

    A worker's :class:`SoftsbiError` (e.g. an :class:`EnvironmentFault`) is raised, unless it is one of
    ``contained`` (e.g. a :class:`~softsbi.core.errors.ParameterError` of one job's effect, which concerns that job
    only); any other exception, or a crashed worker, becomes a failed result (:func:`failed`: ``STATUS_ERROR`` and
    its reason). The failed simulations and those the engine warned about are told once at the end, the first few
    with their parameters (:class:`~softsbi.workflows.reporting.SimulationIssues`).
    """
    out: list[JobResult | None] = [None] * len(items)
    count = BankCount()
    issues = SimulationIssues(ctx.param_names)
    with pools.executor(executor, workers, executor_options) as exe, phase(label, len(items)) as advance:
        for done, (i, res) in enumerate(map_simulations(exe, ctx, items), start=1):
            if isinstance(res, BaseException):
                if isinstance(res, SoftsbiError) and not isinstance(res, contained):
                    raise res
                res = failed(res)
            out[i] = res
            count.add(res.bank)
            issues.add(items[i].theta, res.ok, res.reason, res.warning)
            advance(done, count.hits)
        if count.wrong_key or count.unstored:
            notify(count.warning(ctx.bank))
        if (line := issues.line(label)) is not None:
            notify(line)
    return out  # type: ignore[return-value]
