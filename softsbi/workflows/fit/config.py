"""The settings of a fit (:class:`FitConfig`): their defaults, checks, what a resume compares, the frames a fit
uses and the parameter space it infers. The CLI's ``fit`` and the Python API share them;
:func:`~softsbi.workflows.fit.run.run_fit` runs them.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, Mapping

import numpy as np

from softsbi.backends.scenario_build import unsupported
from softsbi.core.errors import ParameterError, SoftsbiError
from softsbi.core.types import ParamSpace, Recording, Scenario
from softsbi.plugins import check_options, registry
from softsbi.core import defaults
from softsbi.workflows.fit.prior_widening import check_widen


#: proposal schemes of sequential fits (see :class:`FitConfig`)
PROPOSALS = ("corrected", "truncated")
#: ``frames="auto"``: frames in which the gripper is at least this high above the table (m); in
#: the DiffCloud recordings the cloud is complete only once the cloth hangs clear (frame 10 on)
LIFTED_HEIGHT = 0.10
#: keys of the stored run configuration that come from the recording, not from :class:`FitConfig`,
#: and must match on resume
RECORDING_RESUME_KEYS = ("scenario", "param_space", "observed_source", "observer_options")
#: the bound of each count of a fit's settings (:class:`~softsbi.core.defaults.Bound`): :meth:`FitConfig.validate`
#: refuses a value outside it with the words the CLI's flag refuses it with, so a Python API call and the command
#: cannot disagree
COUNT_BOUNDS: Mapping[str, defaults.Bound] = {
    "seed": defaults.SEED_BOUND, "rounds": defaults.ROUNDS_BOUND, "sims_per_round": defaults.SIMS_BOUND,
    "workers": defaults.WORKERS_BOUND, "n_points": defaults.POINTS_BOUND, "n_eval": defaults.EVAL_BOUND,
    "sensor_draws": defaults.SENSOR_DRAWS_BOUND, "refine": defaults.REFINE_BOUND}
#: values of resume keys in runs written before the key existed
RESUME_DEFAULTS = {"proposal": "corrected", "truncation_eps": 1e-3, "sensor": "height", "sensor_draws": 0,
                   "start_box": {}}


#: scenario options that say where a scenario was read from, not what it is: a run resumes whatever path the
#: same scenario file is read from now (a moved checkout, another install of softsbi); and the keyframe times
#: of its gripper path, which the path itself holds (runs stored before they were kept resume)
SCENARIO_PROVENANCE = ("source", "file", "keyframe_times")
#: what a scenario declares for seeing it: its cameras and figures' view, and where the visual arm of rendered
#: images stands. The simulated states do not depend on them (rendered images do, and an image fit compares its
#: camera through its observer options); runs written before scenarios declared them derived the same from the
#: scenario's name
SCENARIO_PRESENTATION = ("cameras", "view")
SCENARIO_PRESENTATION_OPTIONS = ("robot_base",)
#: backend options that change how fast the simulations run, not their results (the simulator's
#: :attr:`~softsbi.core.interfaces.Simulator.batch_size`): left out of what a resume compares, the simulation bank's
#: keys and the stored tasks' keys
SPEED_OPTIONS = ("batch_size",)


def resume_identity(key: str, value: Any) -> Any:
    """What a resume compares of a stored setting: the value itself, except the scenario without its
    provenance options (:data:`SCENARIO_PROVENANCE`) and presentation (:data:`SCENARIO_PRESENTATION`), and the
    backend options without the speed knobs (:data:`SPEED_OPTIONS`)."""
    if key == "backend_options" and isinstance(value, Mapping):
        return {k: v for k, v in value.items() if k not in SPEED_OPTIONS}
    if key == "scenario" and isinstance(value, dict) and isinstance(value.get("options"), dict):
        drop = SCENARIO_PROVENANCE + SCENARIO_PRESENTATION_OPTIONS
        return {**{k: v for k, v in value.items() if k not in SCENARIO_PRESENTATION},
                "options": {k: v for k, v in value["options"].items() if k not in drop}}
    return value


def _resume(default: Any = None, factory: Any = None) -> Any:
    """A :class:`FitConfig` field whose value must match when a stored run is resumed."""
    if factory is not None:
        return field(default_factory=factory, metadata={"resume": True})
    return field(default=default, metadata={"resume": True})


@dataclass
class FitConfig:
    """Settings of a fit: the CLI's ``softsbi fit`` options and the Python API share these
    defaults. Stored in the run (:meth:`to_json`) and compared on resume (:meth:`resume_keys`).

    Attributes:
        backend: simulator plugin name.
        backend_options: keyword options of the simulator's constructor (e.g. ``{"grid": 8}``).
        effects: effect plugin names switched on; their parameters join the inferred ones.
        observer: observer plugin name; ``n_points`` = K points per frame (point-cloud observers;
            image observers take K from their extractor).
        observer_options: extra constructor options of the observer, e.g. for the image observers
            ``{"extractor": "heatmap.pt", "size": 128}``.
        estimator: posterior-estimator plugin name; ``estimator_options`` its config.
        rounds: number of sequential rounds (may be raised on resume); None (the default): 1 when the fit's task
            was trained by ``softsbi task train`` (:mod:`~softsbi.workflows.fit.task_store`: its trained posterior conditioned
            on the recording), else :data:`~softsbi.core.defaults.ROUNDS`. sims_per_round: simulations per round (the simulation
            budget is ``rounds * sims_per_round``).
        seed: fixes every draw and every simulation seed.
        n_eval: rollouts at final-posterior samples (the posterior predictive) for the reported Chamfer.
        n_dense: points sampled per simulated frame for the Chamfer distance.
        workers: simulation worker processes (None = one per core).
        executor: executor plugin name.
        executor_options: keyword options of the executor's constructor besides ``workers``
            (e.g. ``{"timeout": 120, "retries": 2}``, ``{"address": "10.0.0.5:6379"}`` for ray).
        bounds: prior-bound overrides ``{name: (low, high)}`` in physical units.
        fixed: parameters held at a value instead of inferred ``{name: value}``.
        min_height: sensor model of the observed state (m): points closer than this to the table
            are not observed, in simulation and recording alike (0 = all visible). None = the
            recording's own sensor model (:attr:`Recording.min_height`: 0.01 m for DiffCloud depth
            clouds, which hold no cloth lying flat; all visible for a simulated recording). The
            reported Chamfer sees the simulated and the measured clouds through the same model
            (:func:`metric_sensor`).
        frames: the frames whose state informs the posterior: indices, ``"all"``, ``"auto"`` (the
            gripper at least 10 cm above the table) or a spec like ``"10:25"`` / ``"0,5,10"``.
            None = the recording's own choice (:attr:`Recording.frames`). The reported Chamfer
            (``chamfer_prior_m``, ``chamfer_posterior_m``) is the mean over these frames; every
            frame's value is kept (:func:`metric_sensor`).
        proposal: how round r+1 draws its parameters (sequential estimators only):
            ``"truncated"`` (the default; TSNPE, Deistler et al. 2022): from the prior restricted to
            the ``1 - truncation_eps`` highest-density region of round r's posterior, and the
            posterior is ``q`` itself (no importance weights, robust when the rounds narrow
            down fast in many dimensions); ``"corrected"`` (BayesSim, the paper's Alg. 1): from
            round r's posterior, the final posterior ``p/p~ * q``. The default was chosen on the
            real lift recordings (the real-lift suite's recordings and metric): tuned on
            the first repeat of each fabric, checked on the second; runs stored before the field
            existed resume as ``"corrected"``.
        truncation_eps: posterior mass outside the truncated proposal's region.
        sensor: the sensor model of the per-frame metric: ``"height"`` (the height cut ``min_height``
            applied to simulated and measured clouds) or ``"camera"`` (simulated clouds made by the
            recording's virtual depth sensor, :class:`~softsbi.perception.depth_sensor.VirtualDepthSensor`,
            measured clouds as recorded; DiffCloud recordings with ``calib_*`` folders only). The
            point-cloud observer then draws the simulated frames' K points from the same sensor's clouds
            and the recorded frames' from the clouds as recorded (``observer_options["camera"]``).
        sensor_draws: K >= 1: every simulation is observed K more times, at K further values of the sensor
            effects' parameters (effects acting only through an observation transform, e.g. ``time-offset``,
            ``point-noise``), drawn from the round's proposal given the simulation's other parameters; the
            estimator trains on all ``(K + 1) n`` pairs. A sensor effect needs no new simulation, so this
            multiplies the training pairs along its parameters at no simulation cost; the pairs are draws of
            the same joint proposal, correlated within a simulation. Only for the point-cloud observer with
            the height sensor model, truncated proposals or bulk estimators, and when every observation
            transform of the fit is such a sensor effect; otherwise, and at 0 (the default), it does nothing.
            ``diagnose``'s refits use 0, so that physics and sensor effects are refitted on the same footing.
        refine: N >= 1: after the posterior, N more simulations polish the best fit by CMA-ES started at the
            posterior's mean with its covariance, inside the prior (:func:`~softsbi.workflows.fit.bestfit.refine`;
            stored in the run, resumable, the posterior untouched). 0 (the default): the best fit is the best of
            the fit's own simulations. ``report.json``'s ``best_fit`` holds it either way.
        widen: after each round but the last, move a prior bound that the posterior presses (and that is not a
            physical limit) outward by the rule ``fit`` prints, for the following rounds; the widened prior is
            the run's prior of record (:mod:`~softsbi.workflows.fit.prior_widening`). Truncated proposals with a sequential
            estimator only. Default False: the rounds before a widening under-weight the region beyond the old
            bound (see that module), so it is an option.
        start_box: ``{name: [low, high]}`` in physical units: the first round draws from the prior restricted to
            this box (every parameter not named keeps its whole prior range) instead of the whole prior, a
            truncated proposal whose region is a box (as in truncated marginal neural ratio estimation, Miller et al.
            2021); the posterior is then ``q`` restricted to the prior box, exact when the box holds the posterior's
            mass. Truncated proposals with a sequential estimator and no sensor draws only; the first round is then
            never a stored task.
            ``diagnose`` starts a pair's refit in the box of its singles' posteriors
            (:func:`~softsbi.workflows.criticism.evidence.start_box`). Default: none, the first round draws from the
            prior.
    """

    backend: str = _resume(defaults.BACKEND)
    backend_options: dict[str, Any] = _resume(factory=dict)
    effects: list[str] = _resume(factory=list)
    observer: str = _resume(defaults.OBSERVER)
    n_points: int = defaults.N_POINTS
    observer_options: dict[str, Any] = field(default_factory=dict)
    estimator: str = _resume(defaults.ESTIMATOR)
    estimator_options: dict[str, Any] = field(default_factory=dict)
    rounds: int | None = None
    sims_per_round: int = _resume(defaults.SIMS_PER_ROUND)
    seed: int = _resume(defaults.SEED)
    n_eval: int = defaults.N_EVAL
    n_dense: int = 600
    workers: int | None = None
    executor: str = defaults.EXECUTOR
    executor_options: dict[str, Any] = field(default_factory=dict)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    fixed: dict[str, float] = field(default_factory=dict)
    min_height: float | None = _resume(None)
    frames: list[int] | str | None = _resume(None)
    proposal: str = _resume(defaults.PROPOSAL)
    truncation_eps: float = _resume(1e-3)
    sensor: str = _resume(defaults.SENSOR)
    sensor_draws: int = _resume(0)
    refine: int = 0
    widen: bool = False
    sim_bank: str = defaults.SIM_BANK
    start_box: dict[str, list[float]] = _resume(factory=dict)

    def validate(self) -> None:
        """Raise :class:`SoftsbiError` naming the option and the fix for a setting out of range (a count outside its
        :data:`COUNT_BOUNDS`, e.g. above its maximum: the line names the flag, the value, the bound and why), or for a
        plugin option that its plugin does not have or that is text where a number is expected
        (:func:`~softsbi.plugins.check_options`; ``PluginNotFound`` for an unknown plugin), or an
        estimator or a backend that cannot be constructed (``ParameterError``: its options refused; ``PluginError``:
        its code failed, :meth:`~softsbi.plugins.manager.Registry.create`) or lacks an optional dependency
        (``DependencyMissing``, :meth:`~softsbi.core.interfaces.Simulator.check_installed`)."""
        if self.proposal not in PROPOSALS:
            raise SoftsbiError(f"--proposal must be one of {list(PROPOSALS)} (got {self.proposal!r})")
        if self.sensor not in ("height", "camera"):
            raise SoftsbiError(f"--sensor must be 'height' or 'camera' (got {self.sensor!r})")
        if not 0 < self.truncation_eps < 0.5:
            raise SoftsbiError(f"truncation_eps must lie in (0, 0.5) (got {self.truncation_eps})")
        if not isinstance(self.sensor_draws, int) or self.sensor_draws < 0:
            raise SoftsbiError(f"sensor_draws must be an integer >= 0 (got {self.sensor_draws!r})")
        if not isinstance(self.refine, int) or self.refine < 0:
            raise SoftsbiError(f"--refine must be an integer >= 0 (got {self.refine!r}); 0 = no refinement")
        for name, bound in COUNT_BOUNDS.items():  # each count's least and largest value (None: unset, accepted)
            why = bound.problem(getattr(self, name))
            if why is not None:
                field_name = "" if bound.flag == "--" + name.replace("_", "-") else f" ({name})"
                raise SoftsbiError(f"{bound.flag}{field_name} {why}")
        if self.min_height is not None and self.min_height < 0:
            raise SoftsbiError(f"--min-height must be >= 0 m (got {self.min_height})")
        if isinstance(self.frames, list) and len(self.frames) < 1:
            raise SoftsbiError("--frames selects no frame; give e.g. --frames 10:25")
        if isinstance(self.frames, str):
            parse_frames(self.frames, None)
        # the plugins' options, before the first simulation (an estimator's are otherwise read after a round)
        reg = registry()
        for lookup, kind, name, opts, flag in (
                (reg.simulator, "simulator", self.backend, self.backend_options, "--backend-opt"),
                (reg.estimator, "estimator", self.estimator, self.estimator_options, "--estimator-opt"),
                (reg.executor, "executor", self.executor, self.executor_options, "executor option")):
            check_options(lookup(name), opts, f"{kind} '{name}' ({flag})")
        size = self.backend_options.get("batch_size", 1)
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise SoftsbiError(f"--backend-opt batch_size must be an integer >= 1 (got {size!r}): the simulations "
                               f"one simulate_batch call steps together; 1 = one at a time")
        if self.start_box:
            bad = {k: v for k, v in self.start_box.items() if len(v) != 2 or not float(v[0]) < float(v[1])}
            if bad:
                raise SoftsbiError(f"start_box needs [low, high] with low < high per parameter (got {bad})")
            if self.proposal != "truncated" or not getattr(reg.estimator(self.estimator), "sequential", True) \
                    or self.sensor_draws:
                raise SoftsbiError("start_box needs truncated proposals, a sequential estimator and no sensor draws "
                                   "(--proposal truncated with rkhs, mdnn, ...; --sensor-draws 0): the box is a "
                                   "truncated proposal of every parameter")
        if self.widen:
            check_widen(self.proposal, bool(getattr(reg.estimator(self.estimator), "sequential", True)),
                        self.sensor_draws)
        # e.g. a missing optional dependency, named now, before the run directory is made
        reg.create("estimator", self.estimator, self.estimator_options, f"estimator '{self.estimator}' (--estimator-opt)")
        reg.create("simulator", self.backend, self.backend_options, f"simulator '{self.backend}' (--backend-opt)"
                   ).check_installed()

    def to_json(self) -> dict[str, Any]:
        """Every setting as a JSON-able dict (bounds as ``[low, high]`` lists)."""
        d = asdict(self)
        d["bounds"] = {k: [float(v[0]), float(v[1])] for k, v in self.bounds.items()}
        return d

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "FitConfig":
        """The inverse of :meth:`to_json`; keys that are not settings are ignored.

        Raises:
            SoftsbiError: a value of the wrong type (e.g. bounds that are not pairs).
        """
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in d.items() if k in names}
        bounds = kw.get("bounds") or {}
        try:
            kw["bounds"] = {k: (float(v[0]), float(v[1])) for k, v in bounds.items()}
        except (TypeError, IndexError, ValueError):
            raise SoftsbiError(f"FitConfig bounds must map names to [low, high] pairs (got {bounds!r})") from None
        for k in ("backend_options", "observer_options", "estimator_options", "executor_options", "fixed"):
            kw[k] = dict(kw.get(k) or {})
        kw["effects"] = list(kw.get("effects") or [])
        return cls(**kw)

    @classmethod
    def from_run_config(cls, config: Mapping[str, Any]) -> "FitConfig":
        """The settings a stored run was fitted with (``RunStore.config``). Runs written before
        the full settings were stored rebuild them from the stored keys."""
        if "fit_config" in config:
            return cls.from_json(config["fit_config"])
        legacy = dict(config)
        obs = dict(legacy.get("observer_options") or {})
        legacy.setdefault("n_points", int(obs.get("n_points", 64)))
        # the stored observer options were computed from the settings (K, table height, occluder)
        legacy["observer_options"] = {k: v for k, v in obs.items()
                                      if k not in ("n_points", "min_z", "viewpoint", "occluder", "scenario")}
        return cls.from_json(legacy)

    @classmethod
    def resume_keys(cls) -> tuple[str, ...]:
        """Stored-config keys that must match for a run to resume: the settings that change what
        the stored simulations mean, plus those that come from the recording."""
        return tuple(f.name for f in fields(cls) if "resume" in f.metadata) + RECORDING_RESUME_KEYS

    def resolved(self, recording: Recording) -> "FitConfig":
        """These settings with the recording's defaults filled in: ``min_height`` and ``frames``
        from the recording's sensor model when None, frame specs turned into indices (``None`` =
        every frame); image observers see whole frames (no height cut).

        Raises:
            SoftsbiError: a frame spec that is not indices or ranges.
        """
        min_height = self.min_height if self.min_height is not None else recording.min_height
        frames = self.frames if self.frames is not None else recording.frames
        if needs_images(self):
            min_height = None
            frames = None if frames in ("auto", "all") else frames
        given_by = "--frames" if self.frames is not None else "the recording's sensor.frames"
        return replace(self, min_height=min_height, frames=parse_frames(frames, recording.scenario, given_by))


#: the metric of point-cloud fits (3-D Chamfer, m) and of image fits (mask Chamfer, px), as a run stores it
CHAMFER_M, MASK_CHAMFER_PX = "chamfer_m", "mask_chamfer_px"


@dataclass(frozen=True, kw_only=True)
class RunRecord:
    """What a run's stored settings (``RunStore.config``) hold beside its :class:`FitConfig`: what the fit took
    from its recording and the metric it scored with (:func:`~softsbi.workflows.fit.resume.stored_config`).
    A key that a run written by an older version lacks reads as its default.

    Attributes:
        scenario: the fitted scenario (JSON, as stored: the simulation bank keys its rollouts by it).
        param_space: the inferred parameters (JSON), widened ones included.
        observer_options: the observer's options as the fit built it (the settings' own plus those computed from
            the recording: K, table height, viewpoint), what a re-simulation observes with.
        observed_source: where the measurement was read from ("" unknown). truth: its ground truth, if any.
        metric: :data:`CHAMFER_M` or :data:`MASK_CHAMFER_PX`.
        metric_min_z: the metric's height cut (m, absolute; None = full clouds). metric_frames: the frames the
            headline Chamfer averages (None = all). metric_camera: the metric's virtual depth sensor (JSON;
            None = the height cut) (:func:`~softsbi.workflows.fit.observe.metric_sensor`).
        rounds: the rounds of the latest session (a resume may ask for more than the first).
        wall_time_s: the wall time of the fit's sessions so far (s).
    """

    scenario: dict[str, Any]
    param_space: list[dict[str, Any]]
    observer_options: dict[str, Any] = field(default_factory=dict)
    observed_source: str = ""
    truth: Any = None
    metric: str = CHAMFER_M
    metric_min_z: float | None = None
    metric_frames: list[int] | None = None
    metric_camera: dict[str, Any] | None = None
    rounds: int | None = None
    wall_time_s: float = 0.0

    def __post_init__(self) -> None:  # the stored JSON's values as the attributes' types
        put = object.__setattr__
        put(self, "observer_options", dict(self.observer_options))
        put(self, "observed_source", str(self.observed_source))
        put(self, "wall_time_s", float(self.wall_time_s))
        if self.metric_min_z is not None:
            put(self, "metric_min_z", float(self.metric_min_z))
        if self.metric_frames is not None:
            put(self, "metric_frames", [int(i) for i in self.metric_frames])

    @property
    def image_fit(self) -> bool:
        """Whether the fit scored the mask Chamfer of rendered frames (no 3-D clouds)."""
        return self.metric == MASK_CHAMFER_PX

    @classmethod
    def from_run_config(cls, config: Mapping[str, Any]) -> "RunRecord":
        """The record of a stored run's settings (``RunStore.config``); keys a run lacks (or holds as null) read as
        the defaults."""
        return cls(**{f.name: config[f.name] for f in fields(cls) if config.get(f.name) is not None})


def estimator_options(cfg: FitConfig, est_cls: type) -> dict[str, Any]:
    """The options a fit gives its posterior estimator: those the model's effects ask for
    (:attr:`~softsbi.core.interfaces.Effect.estimator_options`) where ``est_cls`` has the option (its
    ``defaults()``), then the user's ``cfg.estimator_options`` over them.

    Raises:
        PluginNotFound: an effect of ``cfg.effects`` is not installed.
    """
    known = est_cls.defaults() if hasattr(est_cls, "defaults") else {}
    asked: dict[str, Any] = {}
    for e in cfg.effects:
        asked.update({k: v for k, v in registry().effect(e).estimator_options.items() if k in known})
    return {**asked, **cfg.estimator_options}


def parse_frames(spec: list[int] | str | None, scenario: Scenario | None,
                 given_by: str = "--frames") -> list[int] | None:
    """Frame indices of a frame spec: ``None``/``"all"`` -> None (every frame); ``"auto"`` -> the
    frames where the gripper is at least :data:`LIFTED_HEIGHT` above the table (None if none or
    no scenario); ``"10:25"`` / ``"0,5,10"`` / a list -> indices. ``given_by``: where the spec comes from, for
    the message (``--frames``, or the recording's sensor model).

    Raises:
        SoftsbiError: a spec that is not indices or ranges, or (with ``scenario``) an index outside its frames.
    """
    out = _frame_indices(spec, scenario)
    if out is not None and scenario is not None:
        T = scenario.n_frames
        bad = [i for i in out if not 0 <= i < T]
        if bad:
            fix = f"e.g. --frames {T // 2}:{T}" if given_by == "--frames" else "or override them with --frames"
            raise SoftsbiError(f"{given_by} {_frames_text(spec)} selects frame {bad[0]}, but the recording has {T} "
                               f"frames (0 to {T - 1}); give frames within them, {fix}")
    return out


def _frames_text(spec: Any) -> str:
    return ",".join(str(i) for i in spec) if isinstance(spec, (list, tuple)) else str(spec)


def _frame_indices(spec: list[int] | str | None, scenario: Scenario | None) -> list[int] | None:
    """:func:`parse_frames` before the range check."""
    if spec is None or spec == "all":
        return None
    if isinstance(spec, (list, tuple)):
        return [int(i) for i in spec]
    if spec == "auto":
        if scenario is None:
            return None
        h = scenario.gripper[:, 2] - scenario.table_z
        lifted = [int(i) for i in np.nonzero(h >= LIFTED_HEIGHT)[0]]
        return lifted or None
    out: list[int] = []
    try:
        for part in str(spec).split(","):
            if ":" in part:
                a, b = part.split(":")
                out.extend(range(int(a), int(b)))
            else:
                out.append(int(part))
    except ValueError:
        raise SoftsbiError(f"--frames '{spec}' must be all, auto, or indices and ranges like 10:25 or 0,5,10") from None
    return out


def needs_images(cfg: FitConfig) -> bool:
    """Whether the fit's observer works on rendered frames (``heatmap``, ``transporter``)."""
    return bool(getattr(registry().observer(cfg.observer), "needs_images", False))


def fit_param_space(cfg: FitConfig, scenario: Scenario) -> tuple[ParamSpace, ParamSpace]:
    """The full parameter space (backend + effects, bounds overridden) and the inferred
    sub-space (without ``cfg.fixed``).

    Raises:
        PluginNotFound, ParameterError: unknown backend/effect, unsupported effect/scenario. PluginError: a plugin's
            code fails to declare its parameters, or two declare one name (:meth:`Registry.param_space`).
    """
    reg = registry()
    sim_cls = reg.simulator(cfg.backend)
    why = unsupported(sim_cls, scenario)
    if why:
        raise ParameterError(why)
    for e in cfg.effects:
        missing = sim_cls.supports(reg.effect(e))
        if missing is not None:
            raise ParameterError(f"backend '{cfg.backend}' cannot apply effect '{e}': it needs {missing}")
    space = reg.param_space(sim_cls(**cfg.backend_options), scenario, cfg.effects)
    if cfg.bounds:
        space = space.with_bounds(cfg.bounds)
    try:
        space.check(cfg.fixed, allow_missing=True)
    except ParameterError as exc:
        raise ParameterError(f"{exc} (--fix), or widen the prior with --bounds name=low:high") from None
    inferred = ParamSpace([p for p in space if p.name not in cfg.fixed])
    if inferred.dim == 0:
        raise ParameterError("every parameter is fixed; leave at least one to infer")
    return space, inferred


def parameter_table(cfg: FitConfig, scenario: Scenario) -> list[dict[str, Any]]:
    """Every parameter a fit of ``scenario`` with ``cfg``'s backend and effects infers or holds (``softsbi
    params``): the backend's parameter space for the scenario, then each effect's, with ``cfg.bounds`` applied;
    each row is :meth:`~softsbi.core.types.Param.summary` with its ``source`` (the backend's or the effect's
    name).

    Raises:
        as :func:`fit_param_space`.
    """
    space, _ = fit_param_space(cfg, scenario)
    source = dict.fromkeys(space.names, cfg.backend)
    for e in cfg.effects:
        source.update(dict.fromkeys(registry().effect(e)().param_space().names, e))
    return [{**p.summary(), "source": source[p.name]} for p in space]
