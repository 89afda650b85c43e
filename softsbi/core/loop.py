"""The sequential real-to-sim loop (BayesSim, Ramos et al. 2019; Antonova et al. 2022, Alg. 1).

Round 1 draws ``sims_per_round`` parameters from the prior; round r+1 draws them from the
corrected posterior of round r (:class:`~softsbi.core.distributions.PosteriorChain`), or with
``proposal="truncated"`` from the prior truncated to round r's posterior (TSNPE,
:class:`~softsbi.core.distributions.TruncatedPrior`). Estimators with ``sequential = False``,
the "bulk" baselines, draw every round from the prior and their posterior is ``q`` truncated
to the prior box, so round r reports the bulk method with r x sims_per_round simulations. All
simulations are kept; after each round the estimator is trained on all usable simulations
so far and conditioned on the observation. Everything goes to the run's Zarr store as it
is produced, so ``run_fit`` on an existing run directory resumes where it stopped.

This module resolves simulators, observers, estimators and executors by *name* through
the plugin registry: it imports no simulator.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .distributions import PosteriorChain, RoundPosterior, TruncatedPrior
from .errors import EnvironmentFault, PosteriorError, SoftsbiError
from .metrics import chamfer_per_frame
from .store import RunStore
from .types import STATUS_ERROR, STATUS_OK, ParamSpace, Scenario

# ----------------------------------------------------------------------------------------
# configuration

#: proposal schemes of sequential fits (see :class:`FitConfig`)
PROPOSALS = ("corrected", "truncated")


@dataclass
class FitConfig:
    """Settings of a fit (stored in the run and compared on resume).

    Attributes:
        backend: simulator plugin name.
        backend_options: keyword options of the simulator's constructor (e.g. ``{"grid": 8}``).
        effects: effect plugin names switched on; their parameters join the inferred ones.
        observer: observer plugin name; ``n_points`` = K points per frame (point-cloud observers;
            image observers take K from their extractor).
        observer_options: extra constructor options of the observer, e.g. for the image observers
            ``{"extractor": "heatmap.pt", "size": 128}``.
        estimator: posterior-estimator plugin name; ``estimator_options`` its config.
        rounds: number of sequential rounds; sims_per_round: simulations per round.
        seed: fixes every draw and every simulation seed.
        n_eval: rollouts at final-posterior samples for the reported Chamfer.
        n_dense: points sampled per simulated frame for the Chamfer distance.
        workers: simulation worker processes (None = one per core).
        executor: executor plugin name.
        executor_options: keyword options of the executor's constructor besides ``workers``
            (e.g. ``{"timeout": 120, "retries": 2}``, ``{"address": "10.0.0.5:6379"}`` for ray).
        bounds: prior-bound overrides ``{name: (low, high)}`` in physical units.
        fixed: parameters held at a value instead of inferred ``{name: value}``.
        min_height: sensor model of the observed state (m): points closer than this to the
            table are not observed, in simulation and measurement alike (None = all visible).
            Does not change the Chamfer metric, which compares full clouds.
        frames: indices of the frames whose state informs the posterior (None = all); the
            metric still uses every frame.
        proposal: how round r+1 draws its parameters (sequential estimators only):
            ``"corrected"`` (BayesSim, the paper's): from round r's posterior ``p/p~ * q``;
            ``"truncated"`` (TSNPE, Deistler et al. 2022): from the prior restricted to the
            ``1 - truncation_eps`` highest-density region of round r's posterior, and the
            posterior is ``q`` itself (no importance weights, robust when the rounds narrow
            down fast in many dimensions).
        truncation_eps: posterior mass outside the truncated proposal's region.
    """

    backend: str = "mujoco-flex"
    backend_options: dict[str, Any] = field(default_factory=dict)
    effects: list[str] = field(default_factory=list)
    observer: str = "pointcloud"
    n_points: int = 64
    observer_options: dict[str, Any] = field(default_factory=dict)
    estimator: str = "rkhs"
    estimator_options: dict[str, Any] = field(default_factory=dict)
    rounds: int = 4
    sims_per_round: int = 150
    seed: int = 0
    n_eval: int = 30
    n_dense: int = 600
    workers: int | None = None
    executor: str = "local"
    executor_options: dict[str, Any] = field(default_factory=dict)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    fixed: dict[str, float] = field(default_factory=dict)
    min_height: float | None = None
    frames: list[int] | None = None
    proposal: str = "corrected"
    truncation_eps: float = 1e-3

    def validate(self) -> None:
        if self.proposal not in PROPOSALS:
            raise SoftsbiError(f"--proposal must be one of {list(PROPOSALS)} (got {self.proposal!r})")
        if not 0 < self.truncation_eps < 0.5:
            raise SoftsbiError(f"truncation_eps must lie in (0, 0.5) (got {self.truncation_eps})")
        if self.rounds < 1:
            raise SoftsbiError(f"--rounds must be >= 1 (got {self.rounds})")
        if self.sims_per_round < 10:
            raise SoftsbiError(f"--sims-per-round must be >= 10 (got {self.sims_per_round}); the estimator needs data")
        if self.workers is not None and self.workers < 1:
            raise SoftsbiError(f"--workers must be >= 1 (got {self.workers})")
        if self.n_points < 1:
            raise SoftsbiError(f"--points must be >= 1 (got {self.n_points})")
        if self.frames is not None and len(self.frames) < 1:
            raise SoftsbiError("--frames selects no frame; give e.g. --frames 10:25")


@dataclass
class Measurement:
    """What we fit to.

    Attributes:
        scenario: the task the measurement was recorded in.
        x: ``(T, 1 + K, 3)`` observed state (gripper row then K points), metres; rebuilt by
            :func:`run_fit` from ``dense`` with the fit's observer settings when the observer
            can observe recorded clouds.
        dense: ``(T, P, 3)`` denser observed clouds (the Chamfer metric's reference), metres.
        source: path of the recording or a description.
        truth: hidden parameter values when the measurement is simulated (else None).
        images: ``(T, H, W, 3)`` uint8 RGB frames for image observers (``heatmap``,
            ``transporter``); their cloth masks are the reference of the mask Chamfer metric.
            ``x`` and ``dense`` may then be None.
    """

    scenario: Scenario
    x: np.ndarray | None
    dense: np.ndarray | None
    source: str
    truth: dict[str, float] | None = None
    images: np.ndarray | None = None


# ----------------------------------------------------------------------------------------
# simulation jobs (run in worker processes)


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


_WORKER_CACHE: dict[str, Any] = {}


def _objects(ctx: SimContext) -> tuple[Any, Any, Scenario]:
    key = json.dumps([ctx.backend, ctx.backend_options, ctx.observer, ctx.observer_options, ctx.scenario],
                     sort_keys=True, default=str)
    if key not in _WORKER_CACHE:
        from ..plugins import registry
        reg = registry()
        sim = reg.simulator(ctx.backend)(**ctx.backend_options)
        obs = reg.observer(ctx.observer)(**ctx.observer_options)
        _WORKER_CACHE.clear()
        _WORKER_CACHE[key] = (sim, obs, Scenario.from_json(ctx.scenario))
    return _WORKER_CACHE[key]


def simulate_job(ctx: SimContext, item: tuple[np.ndarray, int]) -> dict[str, Any]:
    """Simulate one parameter vector and observe it.

    Args:
        ctx: the shared context. item: ``(theta (D,), seed)``.

    Returns:
        ``{"status", "reason", "x" (T, 1+K, 3) or None, "chamfer" (T,) or None, "seconds"}``, plus
        ``vertices``, ``faces``, ``gripper`` when ``ctx.keep_rollout``;
        ``chamfer`` is the 3-D Chamfer (m) against ``ctx.dense``, or the mask Chamfer (px) against
        ``ctx.ref_masks`` for image fits.
    """
    from ..perception.pointcloud import rollout_clouds  # local: workers import lazily

    theta, seed = item
    t0 = time.perf_counter()
    sim, obs, scenario = _objects(ctx)
    values = dict(zip(ctx.param_names, map(float, theta)))
    values.update(ctx.fixed)
    try:
        if getattr(obs, "needs_images", False):
            ro = sim.simulate_images(scenario, values, camera=obs.camera, effects=ctx.effects, seed=int(seed),
                                     style=obs.style)
        else:
            ro = sim.simulate(scenario, values, effects=ctx.effects, seed=int(seed))
    except SoftsbiError:
        raise
    except (ImportError, OSError) as exc:  # the machine cannot simulate: stop, store nothing as failed
        raise EnvironmentFault(f"{ctx.backend} cannot simulate on this machine ({type(exc).__name__}: {exc}); "
                               f"fix the installation and re-run the same command to resume") from exc
    except Exception as exc:  # noqa: BLE001 - an engine error is a failed simulation
        return {"status": STATUS_ERROR, "reason": f"{type(exc).__name__}: {exc}", "x": None, "chamfer": None,
                "seconds": time.perf_counter() - t0}
    if not ro.ok:
        return {"status": int(ro.status), "reason": ro.reason, "x": None, "chamfer": None,
                "seconds": time.perf_counter() - t0}
    rng = np.random.default_rng([int(seed), 17])
    o = obs.observe(ro, rng)
    x = o.state()
    ch = None
    if ctx.ref_masks is not None:
        from ..perception.masks import hsv_mask, mask_chamfer_per_frame
        ch = mask_chamfer_per_frame(hsv_mask(ro.rgb), ctx.ref_masks)
    elif ctx.dense is not None:
        ch = chamfer_per_frame(rollout_clouds(ro, ctx.n_dense, rng), ctx.dense)
    out = {"status": STATUS_OK, "reason": "", "x": x, "chamfer": ch, "seconds": time.perf_counter() - t0}
    if ctx.keep_rollout:
        out.update(vertices=ro.vertices, faces=ro.faces, gripper=ro.gripper)
    return out


# ----------------------------------------------------------------------------------------
# the loop


class Hooks:
    """Progress callbacks of :func:`run_fit` (the CLI draws rich progress bars with them)."""

    def round_start(self, r: int, rounds: int, n_pending: int, n_total: int) -> None: ...
    def simulation_done(self, r: int, done: int, total: int) -> None: ...
    def training_epoch(self, r: int, epoch: int, max_epochs: int, loss: float) -> None: ...
    def round_end(self, r: int, summary: dict[str, Any]) -> None: ...
    def message(self, text: str) -> None: ...


@dataclass
class FitResult:
    """Outcome of :func:`run_fit`; ``report`` is what goes to ``report.json``."""

    store: RunStore
    param_space: ParamSpace
    posterior: RoundPosterior
    report: dict[str, Any]
    rounds: list[dict[str, Any]]


def fit_param_space(cfg: FitConfig, scenario: Scenario) -> tuple[ParamSpace, ParamSpace]:
    """The full parameter space (backend + effects, bounds overridden) and the inferred
    sub-space (without ``cfg.fixed``).

    Raises:
        PluginNotFound, ParameterError: unknown backend/effect, unsupported effect/scenario.
    """
    from ..core.errors import ParameterError
    from ..plugins import registry
    reg = registry()
    sim_cls = reg.simulator(cfg.backend)
    if scenario.name not in sim_cls.scenarios:
        raise ParameterError(f"backend '{cfg.backend}' cannot run scenario '{scenario.name}'; it runs "
                             f"{list(sim_cls.scenarios)}")
    sim = sim_cls(**cfg.backend_options)
    space = sim.param_space(scenario)
    for e in cfg.effects:
        eff_cls = reg.effect(e)
        if e not in sim_cls.effects:
            raise ParameterError(f"backend '{cfg.backend}' cannot apply effect '{e}'; it supports "
                                 f"{list(sim_cls.effects) or 'no effects'}")
        space = space + eff_cls().param_space()
    if cfg.bounds:
        space = space.with_bounds(cfg.bounds)
    space.check(cfg.fixed, allow_missing=True)
    inferred = ParamSpace([p for p in space if p.name not in cfg.fixed])
    if inferred.dim == 0:
        raise ParameterError("every parameter is fixed; leave at least one to infer")
    return space, inferred


def _config_dict(cfg: FitConfig, meas: Measurement, inferred: ParamSpace) -> dict[str, Any]:
    d = asdict(cfg)
    d["bounds"] = {k: list(v) for k, v in cfg.bounds.items()}
    d.update({"scenario": meas.scenario.to_json(), "param_space": inferred.to_json(),
              "observed_source": meas.source, "truth": meas.truth,
              "observer_options": observer_options(cfg, meas.scenario),
              "metric": "mask_chamfer_px" if (needs_images(cfg) and meas.images is not None) else "chamfer_m"})
    d.pop("n_points", None)
    return d


def needs_images(cfg: FitConfig) -> bool:
    """Whether the fit's observer works on rendered frames (``heatmap``, ``transporter``)."""
    from ..plugins import registry
    return bool(getattr(registry().observer(cfg.observer), "needs_images", False))


def observer_options(cfg: FitConfig, scenario: Scenario) -> dict[str, Any]:
    """Constructor options of the observer for this fit: K and the sensor's visibility for point
    clouds; extractor checkpoint, camera and scenario for image observers."""
    if needs_images(cfg):
        opts = dict(cfg.observer_options)
        opts.setdefault("scenario", scenario.name)
        if "extractor" in opts:
            opts["extractor"] = str(Path(opts["extractor"]).resolve())
        return opts
    opts = {"n_points": cfg.n_points}
    if cfg.min_height is not None:
        opts["min_z"] = float(scenario.table_z) + float(cfg.min_height)
    spool = (scenario.object or {}).get("spool")
    if spool and cfg.observer == "pointcloud":  # the wind scenario: the spool hides part of the rope
        from .camera import default_camera
        opts["viewpoint"] = [float(v) for v in default_camera(scenario.name).position]
        opts["occluder"] = {"centre": list(spool["centre"]), "radius": float(spool["radius"]),
                            "z0": float(scenario.table_z), "height": float(spool["height"])}
    opts.update(cfg.observer_options)
    return opts


def observe_measurement(cfg: FitConfig, meas: Measurement) -> np.ndarray:
    """The observed state ``(T, 1+K, 3)`` under the fit's observer settings.

    Raises:
        DataError: an image observer with a measurement that has no frames, or a point-cloud
            observer with one that has neither state nor clouds.
    """
    from ..plugins import registry
    from .errors import DataError
    obs = registry().observer(cfg.observer)(**observer_options(cfg, meas.scenario))
    if getattr(obs, "needs_images", False):
        if meas.images is None:
            raise DataError(f"observer '{cfg.observer}' works on images but the measurement '{meas.source}' has "
                            f"no frames; pass a folder of frames (000.png ...) or use --observer pointcloud")
        return obs.observe_images(meas.images, meas.scenario.gripper, meas.scenario.times, meas.source).state()
    if meas.x is None and meas.dense is None:
        raise DataError(f"measurement '{meas.source}' has no point clouds; observer '{cfg.observer}' needs them "
                        f"(for a folder of frames use --observer heatmap or transporter)")
    if hasattr(obs, "observe_clouds") and meas.dense is not None:
        o = obs.observe_clouds(list(meas.dense), meas.scenario.gripper, meas.scenario.times,
                               np.random.default_rng([cfg.seed, 31337]), source=meas.source)
        return o.state()
    return np.asarray(meas.x, float)


def _round_seeds(seed: int, r: int, n: int) -> np.ndarray:
    return np.random.default_rng([seed, r, 1]).integers(0, 2**31 - 1, size=n)


def evaluation_seeds(seed: int, rounds: int, n_eval: int) -> np.ndarray:
    """``(n_eval,)`` simulation seeds of a fit's final evaluation rollouts (posterior predictive):
    a check that re-simulates the same samples with them reproduces the fit's Chamfer exactly."""
    return _round_seeds(seed, 10_000 + rounds, n_eval)


def _simulate_missing(store: RunStore, r: int, ctx: SimContext, executor: Any, hooks: Hooks) -> None:
    from .executor import WorkerFailure
    data = store.round_data(r)
    for attempt in range(2):  # one retry for jobs whose worker crashed
        pending = store.pending(r)
        if len(pending) == 0:
            return
        items = [(data["theta"][i], int(data["seed"][i])) for i in pending]
        done = len(data["status"]) - len(pending)
        errors = []
        for j, res in executor.map_unordered(simulate_job, items, context=ctx):
            i = int(pending[j])
            if isinstance(res, SoftsbiError):
                raise res
            if isinstance(res, WorkerFailure):  # crashed/hung on every attempt the executor allowed
                store.write_simulation(r, i, None, None, STATUS_ERROR, f"{type(res).__name__}: {res}")
                done += 1
                hooks.simulation_done(r, done, len(data["status"]))
                continue
            if isinstance(res, BaseException):
                errors.append(i)
                if attempt == 1:
                    store.write_simulation(r, i, None, None, STATUS_ERROR, f"{type(res).__name__}: {res}")
                continue
            store.write_simulation(r, i, res["x"], res["chamfer"], res["status"], res["reason"])
            done += 1
            hooks.simulation_done(r, done, len(data["status"]))
        if not errors:
            return
        hooks.message(f"round {r}: {len(errors)} simulations raised in their worker; retrying them once")


def _usable(store: RunStore, upto: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
    us, xs, counts = [], [], []
    for r in range(upto + 1):
        d = store.round_data(r)
        ok = (d["status"] == STATUS_OK) & np.all(np.isfinite(d["x"].reshape(len(d["x"]), -1)), axis=1)
        us.append(d["u"][ok])
        xs.append(d["x"][ok])
        counts.append(int(ok.sum()))
    return np.concatenate(us), np.concatenate(xs), counts


def _chamfer_stats(chamfer: np.ndarray, status: np.ndarray) -> dict[str, Any]:
    ok = (status == STATUS_OK) & np.all(np.isfinite(chamfer), axis=1)
    per_sim = chamfer[ok].mean(1) if ok.any() else np.array([])
    return {"mean_m": float(per_sim.mean()) if len(per_sim) else None,
            "std_m": float(per_sim.std()) if len(per_sim) else None,
            "n": int(ok.sum()), "failed": int((status != STATUS_OK).sum())}


def run_fit(out_dir: str | Path, meas: Measurement, cfg: FitConfig, hooks: Hooks | None = None,
            make_plots: bool = True) -> FitResult:
    """Run (or resume) a sequential fit into ``out_dir``.

    Writes ``out_dir/run.zarr`` as it goes, then ``report.json`` and PNGs.

    Args:
        out_dir: run directory; if it holds a run with the same settings, the fit resumes after
            the last completed step (finished simulations are never redone).
        meas: the measurement (real or simulated).
        cfg: settings; ``cfg.rounds`` may be raised on resume to add rounds.
        hooks: progress callbacks.

    Returns:
        :class:`FitResult`.

    Raises:
        SchemaError: the run directory holds a run with incompatible settings or schema.
        PluginNotFound, ParameterError: bad plugin names, effects or bounds.
    """
    from ..plugins import registry

    hooks = hooks or Hooks()
    cfg.validate()
    t_start = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    reg = registry()
    est_cls = reg.estimator(cfg.estimator)
    sequential = bool(getattr(est_cls, "sequential", True))
    reg.observer(cfg.observer)
    exe_cls = reg.executor(cfg.executor)
    full, space = fit_param_space(cfg, meas.scenario)
    config = _config_dict(cfg, meas, space)
    store_path = out_dir / "run.zarr"
    if RunStore.exists(store_path):
        store = RunStore.open(store_path)
        store.check_resumable(config)
        prev = store.config.get("wall_time_s", 0.0) or 0.0
        hooks.message(f"resuming run in {store_path} after round {len(store.completed_rounds())} "
                      f"({prev:.0f} s spent before)")
    else:
        x0 = observe_measurement(cfg, meas)  # before creating the store: bad input leaves nothing behind
        store = RunStore.create(store_path, config)
        masks = None
        if config["metric"] == "mask_chamfer_px":
            from ..perception.masks import hsv_mask
            masks = hsv_mask(meas.images)
        store.write_observed(x0, meas.scenario.gripper, meas.scenario.times, meas.dense, meas.source,
                             images=meas.images, masks=masks)
        prev = 0.0
    store.update_config(rounds=cfg.rounds)
    observed = store.read_observed()
    x_obs = observed["x"]
    dense = observed.get("dense")
    ref_masks = observed.get("masks")
    metric = store.config.get("metric", "chamfer_m")

    ctx = SimContext(backend=cfg.backend, backend_options=cfg.backend_options, scenario=meas.scenario.to_json(),
                     effects=list(cfg.effects), observer=cfg.observer,
                     observer_options=observer_options(cfg, meas.scenario), param_names=space.names,
                     fixed=dict(cfg.fixed), dense=dense, n_dense=cfg.n_dense,
                     ref_masks=ref_masks if metric == "mask_chamfer_px" else None)
    executor = exe_cls(workers=cfg.workers, **cfg.executor_options)
    chain = PosteriorChain(space.dim, seed=cfg.seed)
    truncated = sequential and cfg.proposal == "truncated"
    summaries: list[dict[str, Any]] = []
    prior_stats: dict[str, Any] | None = None
    try:
        for r in range(cfg.rounds):
            if not store.is_begun(r):
                # bulk estimators (sequential = False): every round draws from the prior
                proposal = None
                if r > 0 and sequential:
                    proposal = chain.posterior(len(chain) - 1)
                    if truncated:
                        proposal = TruncatedPrior(proposal, eps=cfg.truncation_eps, seed=cfg.seed + r)
                rng = np.random.default_rng([cfg.seed, r, 0])
                u = rng.random((cfg.sims_per_round, space.dim)) if proposal is None else \
                    proposal.sample(cfg.sims_per_round, rng)
                what = "prior" if proposal is None else (
                    f"prior truncated to the {1 - cfg.truncation_eps:g} region of round {r - 1}'s posterior "
                    f"(prior mass {proposal.prior_mass:.3g})" if truncated else f"posterior of round {r - 1}")
                store.begin_round(r, space.from_unit(u), u, _round_seeds(cfg.seed, r, cfg.sims_per_round),
                                  x_obs.shape, what)
            hooks.round_start(r, cfg.rounds, len(store.pending(r)), cfg.sims_per_round)
            _simulate_missing(store, r, ctx, executor, hooks)
            d = store.round_data(r)
            stats = _chamfer_stats(d["chamfer"], d["status"]) if (dense is not None or ref_masks is not None) else {}
            if r == 0:
                prior_stats = stats
            elif summaries:
                summaries[-1]["chamfer_posterior"] = stats  # round r draws from posterior r-1
            U, X, counts = _usable(store, r)
            if counts[r] == 0:
                reasons = sorted(set(store.round_attrs(r)["failures"].values()))
                raise SoftsbiError(f"round {r}: every simulation failed, e.g. {reasons[:3]}; narrow the prior "
                                   f"bounds with --bounds or change backend options (finished simulations are "
                                   f"kept in {store.path})")
            if store.is_complete(r):
                q = store.read_q(r)
                info = store.round_attrs(r).get("info", {})
            else:
                est = est_cls(**cfg.estimator_options)
                fr = slice(None) if cfg.frames is None else list(cfg.frames)
                kw = {}
                info = est.fit(U.astype(np.float64), X[:, fr].astype(np.float64), seed=cfg.seed + r,
                               progress=lambda e, m, l, _r=r: hooks.training_epoch(_r, e, m, l), **kw)
                q = est.conditional(x_obs[fr])
                info = dict(info, n_train_total=int(len(U)), usable_per_round=counts)
                store.finish_round(r, q, info)
            if sequential and not truncated:
                post = chain.add_round(q, counts[r])
            else:  # bulk (all data from the prior) or truncated proposals (TSNPE): the posterior
                # is q restricted to the prior box, with no importance weights
                chain = PosteriorChain(space.dim, seed=cfg.seed)
                post = chain.add_round(q, sum(counts))
            try:
                mean_u, cov_u = post.moments(4000, seed=cfg.seed + r)
            except PosteriorError as exc:
                raise PosteriorError(f"round {r}: estimator '{cfg.estimator}' conditioned on the measurement: {exc}. "
                                     f"Try another estimator (e.g. rkhs), more --sims-per-round or wider --bounds; "
                                     f"the finished simulations are kept in {store.path}") from exc
            summaries.append({"round": r, "simulations": int(len(d["status"])), "usable": counts[r],
                              "failed": int((d["status"] != STATUS_OK).sum()),
                              "chamfer_proposal": stats, "train": info,
                              "mass_in_box": post.mass_in_box,
                              "posterior_mean": space.as_dict(space.from_unit(mean_u))})
            hooks.round_end(r, summaries[-1])

        # final evaluation: rollouts at final-posterior samples
        post = chain.posterior(len(chain) - 1)
        ev_stats = _evaluate(store, post, space, ctx, executor, cfg, hooks)
        summaries[-1]["chamfer_posterior"] = ev_stats
    finally:
        executor.close()

    samples = space.from_unit(post.sample(4000, np.random.default_rng([cfg.seed, 99])))
    wall = prev + time.perf_counter() - t_start
    store.update_config(wall_time_s=wall)
    failed = sum(s["failed"] for s in summaries) + ev_stats.get("failed", 0)
    total = sum(s["simulations"] for s in summaries) + cfg.n_eval
    report = {
        "observed": meas.source,
        "backend": cfg.backend, "estimator": cfg.estimator, "effects": cfg.effects,
        "parameters": space.to_json(), "fixed": cfg.fixed,
        "rounds": cfg.rounds, "sims_per_round": cfg.sims_per_round, "simulations": total,
        "proposal": cfg.proposal if sequential else "prior",
        "min_height_m": cfg.min_height, "frames": cfg.frames,
        "failed_simulations": failed,
        "chamfer_prior_m": (prior_stats or {}).get("mean_m"),
        "chamfer_prior_std_m": (prior_stats or {}).get("std_m"),
        "chamfer_posterior_m": ev_stats.get("mean_m"),
        "chamfer_posterior_std_m": ev_stats.get("std_m"),
        "posterior_mean": space.as_dict(samples.mean(0)),
        "posterior_std": space.as_dict(samples.std(0)),
        "posterior_q05": space.as_dict(np.quantile(samples, 0.05, axis=0)),
        "posterior_q95": space.as_dict(np.quantile(samples, 0.95, axis=0)),
        "posterior_median": space.as_dict(np.median(samples, axis=0)),
        "truth": meas.truth,
        "per_round": [{"round": s["round"], "usable": s["usable"], "failed": s["failed"],
                       "chamfer_posterior_m": (s.get("chamfer_posterior") or {}).get("mean_m"),
                       "chamfer_posterior_std_m": (s.get("chamfer_posterior") or {}).get("std_m"),
                       "mass_in_box": s["mass_in_box"], "train_seconds": s["train"].get("seconds"),
                       "posterior_mean": s["posterior_mean"]} for s in summaries],
        "wall_time_s": wall,
    }
    report["metric"] = metric
    if metric == "mask_chamfer_px":  # the paper's image metric: HSV cloth masks, bidirectional Chamfer (px)
        for k in ("prior", "prior_std", "posterior", "posterior_std"):
            report[f"mask_chamfer_{k}_px"] = report.pop(f"chamfer_{k}_m")
            report[f"chamfer_{k}_m"] = None
        for row in report["per_round"]:
            row["mask_chamfer_posterior_px"] = row.pop("chamfer_posterior_m")
            row["mask_chamfer_posterior_std_px"] = row.pop("chamfer_posterior_std_m")
        if report["mask_chamfer_prior_px"] and report["mask_chamfer_posterior_px"]:
            report["chamfer_reduction"] = 1 - report["mask_chamfer_posterior_px"] / report["mask_chamfer_prior_px"]
    elif report["chamfer_prior_m"] and report["chamfer_posterior_m"]:
        report["chamfer_reduction"] = 1 - report["chamfer_posterior_m"] / report["chamfer_prior_m"]
    if meas.truth:
        # an effect added by the fit but absent from the measurement is truly switched off
        truth = dict(meas.truth)
        for e in cfg.effects:
            for k, v in reg.effect(e)().nominal().items():
                truth.setdefault(k, v)
        report["truth"] = truth
        report["truth_in_90pct_interval"] = {
            n: bool(report["posterior_q05"][n] <= truth[n] <= report["posterior_q95"][n])
            for n in space.names if n in truth}
    (out_dir / "report.json").write_text(json.dumps(report, indent=2))
    result = FitResult(store=store, param_space=space, posterior=post, report=report, rounds=summaries)
    if make_plots:
        from ..report import write_fit_plots
        write_fit_plots(out_dir, result, meas, cfg, samples)
    return result


def _evaluate(store: RunStore, post: RoundPosterior, space: ParamSpace, ctx: SimContext, executor: Any,
              cfg: FitConfig, hooks: Hooks) -> dict[str, Any]:
    """Rollouts at ``cfg.n_eval`` final-posterior samples (stored under ``evaluation/``)."""
    if store.has("evaluation"):
        arrays, attrs = store.read_group("evaluation")
        if attrs.get("rounds") == cfg.rounds and len(arrays["status"]) == cfg.n_eval:
            return _chamfer_stats(arrays["chamfer"], arrays["status"])
    rng = np.random.default_rng([cfg.seed, 10_000 + cfg.rounds])
    u = post.sample(cfg.n_eval, rng)
    theta = space.from_unit(u)
    seeds = evaluation_seeds(cfg.seed, cfg.rounds, cfg.n_eval)
    T = len(ctx.scenario["times"])
    chamfer = np.full((cfg.n_eval, T), np.nan)
    status = np.full(cfg.n_eval, STATUS_ERROR, np.uint8)
    hooks.round_start(-1, cfg.rounds, cfg.n_eval, cfg.n_eval)
    done = 0
    for i, res in executor.map_unordered(simulate_job, list(zip(theta, seeds)), context=ctx):
        done += 1
        hooks.simulation_done(-1, done, cfg.n_eval)
        if isinstance(res, BaseException):
            continue
        status[i] = res["status"]
        if res["chamfer"] is not None:
            chamfer[i] = res["chamfer"]
    store.write_group("evaluation", {"theta": theta, "u": u, "status": status, "chamfer": chamfer},
                      attrs={"rounds": cfg.rounds, "what": "rollouts at final-posterior samples"},
                      units={"chamfer": "px" if ctx.ref_masks is not None else "m", "theta": "physical"})
    return _chamfer_stats(chamfer, status)
