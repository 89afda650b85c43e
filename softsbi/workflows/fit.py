"""The sequential real-to-sim fit (BayesSim, Ramos et al. 2019; Antonova et al. 2022, Alg. 1).

Round 1 draws ``sims_per_round`` parameters from the prior; round r+1 draws them from the
prior truncated to round r's posterior (the default, TSNPE,
:class:`~softsbi.core.distributions.TruncatedPrior`), or with ``proposal="corrected"`` (the
paper's BayesSim rounds) from the corrected posterior of round r
(:class:`~softsbi.core.distributions.PosteriorChain`). Estimators with ``sequential = False``,
the "bulk" baselines, draw every round from the prior and their posterior is ``q`` truncated
to the prior box, so round r reports the bulk method with r x sims_per_round simulations. All
simulations are kept; after each round the estimator is trained on all usable simulations
so far and conditioned on the observation. Everything goes to the run's Zarr store as it
is produced, so :func:`run_fit` on an existing run directory resumes where it stopped.

This module resolves simulators, observers, estimators and executors by *name* through
the plugin registry: it imports no simulator. :class:`FitConfig` is the one set of settings
(and defaults) of the CLI's ``fit`` and the Python API.
"""
from __future__ import annotations

import contextlib
import inspect
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from softsbi.core.distributions import MixtureOfGaussians, PosteriorChain, RoundPosterior, TruncatedPrior
from softsbi.core.errors import (DataError, EffectFault, ParameterError, PosteriorDamaged, PosteriorError, SchemaError,
                                  SoftsbiError)
from softsbi.core.interfaces import OBSERVATION
from softsbi.core.store import ROUND_ARRAYS, EstimatorState, RunStore
from softsbi.core.results import ResultDamaged, check_result_path, read_json, write_json_atomic
from softsbi.core.types import STATUS_ERROR, STATUS_OK, STATUS_PENDING, ParamSpace, Recording, Scenario
from softsbi.executors.local import WorkerFailure
from softsbi.inference.contraction import INFORMED_MAX_RATIO, bound_pressure, contraction
from softsbi.perception.masks import hsv_mask
from softsbi.plugins import check_options, registry
from softsbi.workflows.fitplots import write_fit_plots
from softsbi.scenarios.cameras import scenario_camera
from softsbi.workflows import defaults
from softsbi.workflows.bank import BankCount, banks_enabled, check_bank_path, default_bank
from softsbi.workflows.bestfit import REFINE, best_stored, refine, store_best_fit
from softsbi.workflows.jobs import SimContext, _round_seeds, evaluation_seeds, simulate_job
from softsbi.workflows.lock import run_lock
from softsbi.workflows.widen import (check_widen, decide, map_mixture, prior_of_record, reconcile, records,
                                     space_of_round, unit_map, widening_sentence)

# ----------------------------------------------------------------------------------------
# configuration

#: proposal schemes of sequential fits (see :class:`FitConfig`)
PROPOSALS = ("corrected", "truncated")
#: ``frames="auto"``: frames in which the gripper is at least this high above the table (m); in
#: the DiffCloud recordings the cloud is complete only once the cloth hangs clear (frame 10 on)
LIFTED_HEIGHT = 0.10
#: keys of the stored run configuration that come from the recording, not from :class:`FitConfig`,
#: and must match on resume
RECORDING_RESUME_KEYS = ("scenario", "param_space", "observed_source", "observer_options")
#: values of resume keys in runs written before the key existed
RESUME_DEFAULTS = {"proposal": "corrected", "truncation_eps": 1e-3, "sensor": "height", "sensor_draws": 0}


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


def resume_identity(key: str, value: Any) -> Any:
    """What a resume compares of a stored setting: the value itself, except the scenario without its
    provenance options (:data:`SCENARIO_PROVENANCE`) and presentation (:data:`SCENARIO_PRESENTATION`)."""
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
        rounds: number of sequential rounds (may be raised on resume); sims_per_round: simulations
            per round (the simulation budget is ``rounds * sims_per_round``).
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
            posterior's mean with its covariance, inside the prior (:func:`~softsbi.workflows.bestfit.refine`;
            stored in the run, resumable, the posterior untouched). 0 (the default): the best fit is the best of
            the fit's own simulations. ``report.json``'s ``best_fit`` holds it either way.
        widen: after each round but the last, move a prior bound that the posterior presses (and that is not a
            physical limit) outward by the rule ``fit`` prints, for the following rounds; the widened prior is
            the run's prior of record (:mod:`~softsbi.workflows.widen`). Truncated proposals with a sequential
            estimator only. Default False: the rounds before a widening under-weight the region beyond the old
            bound (see that module), so it is an option.
    """

    backend: str = _resume(defaults.BACKEND)
    backend_options: dict[str, Any] = _resume(factory=dict)
    effects: list[str] = _resume(factory=list)
    observer: str = _resume(defaults.OBSERVER)
    n_points: int = defaults.N_POINTS
    observer_options: dict[str, Any] = field(default_factory=dict)
    estimator: str = _resume(defaults.ESTIMATOR)
    estimator_options: dict[str, Any] = field(default_factory=dict)
    rounds: int = defaults.ROUNDS
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

    def validate(self) -> None:
        """Raise :class:`SoftsbiError` naming the option and the fix for a setting out of range, or for a
        plugin option that its plugin does not have or that is text where a number is expected
        (:func:`~softsbi.plugins.check_options`; ``PluginNotFound`` for an unknown plugin), or an
        estimator that cannot be constructed (``DependencyMissing`` for its optional dependency)."""
        if self.proposal not in PROPOSALS:
            raise SoftsbiError(f"--proposal must be one of {list(PROPOSALS)} (got {self.proposal!r})")
        if self.sensor not in ("height", "camera"):
            raise SoftsbiError(f"--sensor must be 'height' or 'camera' (got {self.sensor!r})")
        if not 0 < self.truncation_eps < 0.5:
            raise SoftsbiError(f"truncation_eps must lie in (0, 0.5) (got {self.truncation_eps})")
        if self.seed < 0:
            raise SoftsbiError(f"--seed must be >= 0 (got {self.seed})")
        if not isinstance(self.sensor_draws, int) or self.sensor_draws < 0:
            raise SoftsbiError(f"sensor_draws must be an integer >= 0 (got {self.sensor_draws!r})")
        if self.rounds < 1:
            raise SoftsbiError(f"--rounds must be >= 1 (got {self.rounds})")
        if self.sims_per_round < defaults.MIN_SIMS_PER_ROUND:
            raise SoftsbiError(f"--sims-per-round must be >= {defaults.MIN_SIMS_PER_ROUND} (got {self.sims_per_round}); "
                               f"the estimator needs data")
        if self.workers is not None and self.workers < 1:
            raise SoftsbiError(f"--workers must be >= 1 (got {self.workers})")
        if self.n_points < 1:
            raise SoftsbiError(f"--points must be >= 1 (got {self.n_points})")
        if self.min_height is not None and self.min_height < 0:
            raise SoftsbiError(f"--min-height must be >= 0 m (got {self.min_height})")
        if isinstance(self.frames, list) and len(self.frames) < 1:
            raise SoftsbiError("--frames selects no frame; give e.g. --frames 10:25")
        if isinstance(self.frames, str):
            parse_frames(self.frames, None)
        # the plugins' options, before the first simulation (an estimator's are otherwise read after a round)
        reg = registry()
        for kind, name, opts, flag in (("simulator", self.backend, self.backend_options, "--backend-opt"),
                                       ("estimator", self.estimator, self.estimator_options, "--estimator-opt"),
                                       ("executor", self.executor, self.executor_options, "executor option")):
            check_options(reg.get(kind, name), opts, f"{kind} '{name}' ({flag})")
        if not isinstance(self.refine, int) or self.refine < 0:
            raise SoftsbiError(f"--refine must be an integer >= 0 (got {self.refine!r}); 0 = no refinement")
        if self.widen:
            check_widen(self.proposal, bool(getattr(reg.get("estimator", self.estimator), "sequential", True)),
                        self.sensor_draws)
        reg.estimator(self.estimator)(**self.estimator_options)  # e.g. a missing optional dependency, named now

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
        try:
            kw["bounds"] = {k: (float(v[0]), float(v[1])) for k, v in (kw.get("bounds") or {}).items()}
        except (TypeError, IndexError, ValueError):
            raise SoftsbiError(f"FitConfig bounds must map names to [low, high] pairs (got {kw.get('bounds')!r})") from None
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
        return tuple(f.name for f in fields(cls) if f.metadata.get("resume")) + RECORDING_RESUME_KEYS

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
        return replace(self, min_height=min_height, frames=parse_frames(frames, recording.scenario))


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


def parse_frames(spec: list[int] | str | None, scenario: Scenario | None) -> list[int] | None:
    """Frame indices of a frame spec: ``None``/``"all"`` -> None (every frame); ``"auto"`` -> the
    frames where the gripper is at least :data:`LIFTED_HEIGHT` above the table (None if none or
    no scenario); ``"10:25"`` / ``"0,5,10"`` / a list -> indices.

    Raises:
        SoftsbiError: a spec that is not indices or ranges, or (with ``scenario``) an index outside its frames.
    """
    out = _frame_indices(spec, scenario)
    if out is not None and scenario is not None:
        T = scenario.n_frames
        bad = [i for i in out if not 0 <= i < T]
        if bad:
            raise SoftsbiError(f"--frames {_frames_text(spec)} selects frame {bad[0]}, but the recording has {T} frames "
                               f"(0 to {T - 1}); give frames within them, e.g. --frames {T // 2}:{T}")
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


# ----------------------------------------------------------------------------------------
# progress and results


class FitCallbacks:
    """Progress callbacks of :func:`run_fit` (the CLI draws progress bars with them); every
    method does nothing by default."""

    def round_start(self, r: int, rounds: int, n_pending: int, n_total: int) -> None:
        """Round ``r`` (0-based; -1 = the final posterior-predictive rollouts; -2 = the best fit's refinement,
        ``FitConfig.refine``) begins."""

    def simulation_done(self, r: int, done: int, total: int) -> None:
        """``done`` of ``total`` simulations of round ``r`` are stored."""

    def training_epoch(self, r: int, epoch: int, max_epochs: int, loss: float) -> None:
        """The estimator finished an epoch on round ``r``'s data."""

    def read_from_bank(self, r: int, hits: int, total: int) -> None:
        """``hits`` of the ``total`` simulations of round ``r`` run in this call were read from the simulation bank
        instead of simulated (told once they are all done, only when ``hits > 0``)."""

    def round_end(self, r: int, summary: dict[str, Any]) -> None:
        """Round ``r`` is complete; ``summary`` as in ``report.json``'s ``per_round``."""

    def message(self, text: str) -> None:
        """A notice for the user (resuming, retries)."""


@dataclass
class FitResult:
    """Outcome of :func:`run_fit`; ``report`` is what goes to ``report.json``.

    ``posterior`` samples theta in unit coordinates (``param_space.from_unit`` maps them to
    physical units); :func:`softsbi.open_run` gives the posterior in physical units."""

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
    reg = registry()
    sim_cls = reg.simulator(cfg.backend)
    from softsbi.backends.scenario_build import unsupported
    why = unsupported(sim_cls, scenario)
    if why:
        raise ParameterError(why)
    sim = sim_cls(**cfg.backend_options)
    space = sim.param_space(scenario)
    for e in cfg.effects:
        eff_cls = reg.effect(e)
        missing = sim_cls.supports(eff_cls)
        if missing is not None:
            raise ParameterError(f"backend '{cfg.backend}' cannot apply effect '{e}': it needs {missing}")
        space = space + eff_cls().param_space()
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


def metric_sensor(cfg: FitConfig, scenario: Scenario) -> dict[str, Any]:
    """The fit's sensor model as the metric applies it (issue 17: one definition of the per-frame
    distance for the fit's report, ``check``, ``compare`` and ``diagnose``).

    ``metric_min_z``: simulated and measured points at or below ``table_z + min_height`` (m) are not
    seen (:func:`~softsbi.perception.pointcloud.sensor_view`), None without a height cut;
    ``metric_frames``: the frames the headline Chamfer averages (the fit's ``frames``), None = all.
    ``metric_camera``: with ``cfg.sensor == "camera"`` the recording's virtual depth sensor (JSON,
    :meth:`~softsbi.perception.depth_sensor.VirtualDepthSensor.to_json`, every kept pixel once) that makes
    the simulated clouds, the measured ones used as recorded (``metric_min_z`` None); else None.
    ``cfg`` must be :meth:`FitConfig.resolved`. Image fits (mask Chamfer) get none of them.

    Raises:
        DataError: ``sensor="camera"`` for a recording that is not a calibrated DiffCloud folder.
    """
    if needs_images(cfg):
        return {"metric_min_z": None, "metric_frames": None, "metric_camera": None}
    min_z = float(scenario.table_z) + float(cfg.min_height) if cfg.min_height else None
    frames = None if cfg.frames is None else [int(i) for i in cfg.frames]
    camera = None
    if cfg.sensor == "camera":
        from softsbi.perception.depth_sensor import VirtualDepthSensor
        src = Path(str((scenario.options or {}).get("source", "")))
        if not ((src / "lift_real2sim.yaml").is_file() and (src.parent / "calib_overhead").is_dir()
                and (src.parent / "calib_side").is_dir()):
            raise DataError(f"sensor='camera' needs a DiffCloud recording folder (lift_real2sim.yaml, with "
                            f"calib_overhead/ and calib_side/ beside it), got scenario source '{src}'; use "
                            f"sensor='height' for other recordings")
        camera, min_z = VirtualDepthSensor.for_diffcloud_recording(src, n_points=0).to_json(), None
    return {"metric_min_z": min_z, "metric_frames": frames, "metric_camera": camera}


def _config_dict(cfg: FitConfig, meas: Recording, inferred: ParamSpace) -> dict[str, Any]:
    """What the run store keeps: the settings (also whole, as ``fit_config``) and what comes from
    the recording (scenario, inferred parameter space, source, truth, observer options, metric)."""
    d = cfg.to_json()
    d["fit_config"] = cfg.to_json()
    d.update({"scenario": meas.scenario.to_json(), "param_space": inferred.to_json(),
              "observed_source": meas.source, "truth": meas.truth,
              "observer_options": observer_options(cfg, meas.scenario),
              "metric": "mask_chamfer_px" if (needs_images(cfg) and meas.images is not None) else "chamfer_m",
              **metric_sensor(cfg, meas.scenario)})
    d.pop("n_points", None)
    return d


def needs_images(cfg: FitConfig) -> bool:
    """Whether the fit's observer works on rendered frames (``heatmap``, ``transporter``)."""
    return bool(getattr(registry().observer(cfg.observer), "needs_images", False))


def observer_options(cfg: FitConfig, scenario: Scenario) -> dict[str, Any]:
    """Constructor options of the observer for this fit: K and the sensor's visibility for point
    clouds (with an occluding obstacle, the scenario camera's position as the viewpoint); extractor
    checkpoint and camera (the scenario's, :func:`~softsbi.scenarios.cameras.scenario_camera`) for image
    observers.

    Raises:
        DataError: the scenario declares no camera where one is needed."""
    if needs_images(cfg):
        opts = dict(cfg.observer_options)
        if "camera" not in opts:  # the scenario's own camera (its file's cameras:)
            opts["camera"] = scenario_camera(scenario, int(opts.get("size", 128))).to_json()
        if "extractor" in opts:
            opts["extractor"] = str(Path(opts["extractor"]).resolve())
        return opts
    opts = {"n_points": cfg.n_points}
    if cfg.sensor == "camera" and cfg.observer == "pointcloud":  # the virtual depth sensor replaces the height cut
        opts["camera"] = metric_sensor(cfg, scenario)["metric_camera"]
    elif cfg.min_height:
        opts["min_z"] = float(scenario.table_z) + float(cfg.min_height)
    spool = (scenario.object or {}).get("spool")
    if spool and cfg.observer == "pointcloud":  # an occluding obstacle (the winding's spool) hides what is behind it
        opts["viewpoint"] = [float(v) for v in scenario_camera(scenario).position]  # as seen by its camera
        opts["occluder"] = {"centre": list(spool["centre"]), "radius": float(spool["radius"]),
                            "z0": float(scenario.table_z), "height": float(spool["height"])}
    opts.update(cfg.observer_options)
    return opts


def observe_recording(cfg: FitConfig, meas: Recording) -> np.ndarray:
    """The observed state ``(T, 1+K, 3)`` under the fit's observer settings.

    Raises:
        DataError: an image observer with a measurement that has no frames, or a point-cloud
            observer with one that has neither state nor clouds.
    """
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


def _simulate_missing(store: RunStore, r: int, ctx: SimContext, executor: Any, hooks: FitCallbacks,
                      clock: _Clock | None = None, sensor: "SensorDraws | None" = None) -> None:
    """Simulate round ``r``'s pending simulations and store them; those read from the context's simulation bank
    are counted in the round (:meth:`RunStore.add_bank_hits`, also when interrupted) and told to ``hooks``."""
    count, n = BankCount(), len(store.pending(r))
    try:
        _simulate_pending(store, r, ctx, executor, hooks, count, clock, sensor)
    finally:
        if count.hits:
            with contextlib.suppress(OSError):
                store.add_bank_hits(r, count.hits)
    _tell_bank(hooks, r, count, n, ctx.bank)


def _tell_bank(hooks: FitCallbacks, r: int, count: BankCount, n: int, bank: str | None) -> None:
    """Tell ``hooks`` how many of phase ``r``'s ``n`` simulations were read from ``bank``, and warn once of entries
    stored there under another key."""
    if count.hits:
        hooks.read_from_bank(r, count.hits, n)
    if count.wrong_key:
        hooks.message(count.warning(bank))


def _simulate_pending(store: RunStore, r: int, ctx: SimContext, executor: Any, hooks: FitCallbacks,
                      count: BankCount, clock: _Clock | None, sensor: "SensorDraws | None") -> None:
    data = store.round_data(r, ROUND_ARRAYS + (("sensor_u",) if sensor is not None else ()))
    extra = "sensor_u" in data
    for attempt in range(2):  # one retry for jobs whose worker crashed
        pending = store.pending(r)
        if len(pending) == 0:
            return
        items = [(data["theta"][i], int(data["seed"][i])) + ((None, sensor.job_draws(data["sensor_u"][i]),)
                                                              if extra else ()) for i in pending]
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
            store.write_simulation(r, i, res["x"], res["chamfer"], res["status"], res["reason"],
                                   sensor_x=res.get("sensor_x"))
            count.add(res.get("bank"))
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
        """The worker's ``sensor_draws`` item (:func:`~softsbi.workflows.jobs.simulate_job`) of one simulation's
        ``(K, D)`` unit-cube draws: their sensor parameters in physical units."""
        names = [self.space.names[d] for d in self.dims]
        return {"effects": list(self.effects),
                "draws": [{n: float(v) for n, v in zip(names, self.space.from_unit(row[None])[0][self.dims])}
                          for row in sensor_u]}


def _sensor_pairs(store: RunStore, upto: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stored ``sensor_draws`` pairs of rounds ``<= upto``: ``(m, D)`` unit-cube parameters, their
    ``(m, T, 1+K, 3)`` observations and ``(m,)`` the index of their simulation among :func:`_usable`'s rows; pairs
    of simulations :func:`_usable` keeps, with finite observations (empty when none)."""
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
    return (d["status"] == STATUS_OK) & np.all(np.isfinite(d["x"].reshape(len(d["x"]), -1)), axis=1)


def _usable(store: RunStore, upto: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
    us, xs, counts = [], [], []
    for r in range(upto + 1):
        d = store.round_data(r)
        ok = _usable_rows(d)
        us.append(d["u"][ok])
        xs.append(d["x"][ok])
        counts.append(int(ok.sum()))
    return np.concatenate(us), np.concatenate(xs), counts


def chamfer_stats(chamfer: np.ndarray, status: np.ndarray, frames: list[int] | None = None,
                  one_sided: np.ndarray | None = None) -> dict[str, Any]:
    """Summary of per-frame Chamfer values ``chamfer (N, T)`` of ``N`` simulations with ``status (N,)``:
    each simulation's mean over ``frames`` (None = all), then ``mean_m``/``std_m`` over the successful
    ones, ``per_frame_m (T,)`` (mean over them), ``n``, ``failed``; with ``one_sided (N, T)`` also
    ``one_sided_mean_m``, ``one_sided_std_m``, ``one_sided_per_frame_m``. The fit's report and
    ``check`` both summarise with this, so their numbers agree."""
    fr = slice(None) if frames is None else list(frames)
    ok = (status == STATUS_OK) & np.all(np.isfinite(chamfer), axis=1)
    per_sim = chamfer[ok][:, fr].mean(1) if ok.any() else np.array([])
    out = {"mean_m": float(per_sim.mean()) if len(per_sim) else None,
           "std_m": float(per_sim.std()) if len(per_sim) else None,
           "per_frame_m": chamfer[ok].mean(0).tolist() if ok.any() else None,
           "n": int(ok.sum()), "failed": int((status != STATUS_OK).sum())}
    if one_sided is not None:
        ok1 = ok & np.all(np.isfinite(one_sided), axis=1)
        o = one_sided[ok1][:, fr].mean(1) if ok1.any() else np.array([])
        out.update(one_sided_mean_m=float(o.mean()) if len(o) else None,
                   one_sided_std_m=float(o.std()) if len(o) else None,
                   one_sided_per_frame_m=one_sided[ok1].mean(0).tolist() if ok1.any() else None)
    return out



#: what every reader of a fit's ``report.json`` needs in it (a file without them is damaged)
REPORT_KEYS = ("parameters", "posterior_median")


def read_report(run_dir: str | Path) -> dict[str, Any]:
    """A finished fit's ``report.json``.

    Raises:
        ResultDamaged: it is empty, cut short, not JSON or lacks :data:`REPORT_KEYS`; one line naming it and the
            command that writes it again (the fit's own, which resumes the finished run and rewrites only the
            report).
    """
    run_dir = Path(run_dir)
    return read_json(run_dir / "report.json", f"re-running the fit with the same `softsbi fit ... --out {run_dir}` "
                                              f"command", REPORT_KEYS)


def _damaged_report(run_dir: Path) -> ResultDamaged | None:
    """The error :func:`read_report` raises for ``run_dir``'s ``report.json``; None when it is sound or absent."""
    if not (run_dir / "report.json").exists():
        return None
    try:
        read_report(run_dir)
    except ResultDamaged as exc:
        return exc
    return None


def run_fit(out_dir: str | Path, recording: Recording, cfg: FitConfig | None = None,
            callbacks: FitCallbacks | None = None, make_plots: bool = True, retry_failed: bool = False) -> FitResult:
    """Run (or resume) a sequential fit into ``out_dir``.

    Writes ``out_dir/run.zarr`` as it goes, then ``report.json`` and PNGs.

    Args:
        out_dir: run directory; if it holds a run with the same settings, the fit resumes after
            the last completed step (finished simulations are never redone).
        recording: what to fit (a real recording or a simulated one).
        cfg: settings (default :class:`FitConfig`()); ``cfg.rounds`` may be raised on resume to
            add rounds.
        callbacks: progress callbacks (:class:`FitCallbacks`).
        retry_failed: on resume, simulate the stored failed simulations again (e.g. after fixing the
            environment that made them fail): the earliest round with failures is redone from its
            stored draws and the rounds after it are drawn again from its new posterior.

    Returns:
        :class:`FitResult`.

    Raises:
        RunLocked: another process is writing ``out_dir`` (one writer per run directory).
        SchemaError: the run directory holds a run with incompatible settings or schema.
        PluginNotFound, ParameterError: bad plugin names, effects or bounds.
        EnvironmentFault: the machine cannot simulate; nothing is stored as failed.
        PosteriorError: a round's posterior has no mass in the prior box.
        SoftsbiError: a simulation bank that is empty, a file, cannot be created, or lies inside or around
            ``out_dir`` or the recording (:func:`~softsbi.workflows.bank.check_bank_path`).
    """
    callbacks = callbacks or FitCallbacks()
    cfg = (cfg or FitConfig()).resolved(recording)
    cfg.validate()
    observed = recording.source if recording.source and Path(recording.source).is_dir() else None
    check_bank_path(cfg.sim_bank, {"--out": out_dir, "--observed": observed})
    with run_lock(out_dir):
        check_result_path(Path(out_dir) / "report.json")  # a folder in its place: refused before any simulation
        return _run_fit_locked(Path(out_dir), recording, cfg, callbacks, make_plots, retry_failed)


def _run_fit_locked(out_dir: Path, recording: Recording, cfg: FitConfig, callbacks: FitCallbacks, make_plots: bool,
                    retry_failed: bool) -> FitResult:
    """:func:`run_fit` with the run directory's lock held."""
    reg = registry()
    est_cls = reg.estimator(cfg.estimator)
    exe_cls = reg.executor(cfg.executor)
    _, base = fit_param_space(cfg, recording.scenario)
    space = prior_of_record(out_dir / "run.zarr", base)  # a --widen fit's widened prior
    store, prev = _open_store(out_dir, recording, cfg, space, callbacks)
    damaged = _damaged_report(out_dir)
    if damaged is not None:
        callbacks.message(f"{damaged}: this fit resumes the run and writes it again")
    clock = _Clock(store, prev)
    _repair_damaged(store, callbacks)
    if retry_failed:
        _retry_failed(store, callbacks)
    space = reconcile(store, base, callbacks.message)
    ctx = _sim_context(cfg, recording, store, space)
    loop = _Rounds(cfg, store, space, ctx, est_cls, callbacks, clock)
    executor = exe_cls(workers=cfg.workers, **cfg.executor_options)
    try:
        for r in range(cfg.rounds):
            loop.space = space_of_round(base, store.config, r)
            loop.run_round(r, executor)
            _next_prior(loop, base, r)
        space = loop.space
        post = loop.chain.posterior(len(loop.chain) - 1)
        ev_stats = _evaluate(store, post, space, ctx, executor, cfg, callbacks)
        loop.summaries[-1]["chamfer_posterior"] = ev_stats
        best = _best_fit(store, post, space, ctx, executor, cfg, callbacks) if loop.scored else None
    finally:
        executor.close()
        with contextlib.suppress(OSError):  # also when interrupted: the next session's resume message counts it
            clock.save(force=True)
    samples = space.from_unit(post.sample(4000, np.random.default_rng([cfg.seed, 99])))
    wall = clock.save(force=True)
    report = _report(recording, cfg, space, loop, ev_stats, samples, wall, store.config.get("metric", "chamfer_m"))
    report.update(best_fit=best, widened=records(store.config))
    write_json_atomic(out_dir / "report.json", report)
    if damaged is not None:
        callbacks.message(f"rewrote {damaged.path}, which was damaged ({damaged.problem})")
    result = FitResult(store=store, param_space=space, posterior=post, report=report, rounds=loop.summaries)
    if make_plots:
        write_fit_plots(out_dir, result, recording, cfg, samples,
                        observer_options=observer_options(cfg, recording.scenario))
    return result


def _next_prior(loop: _Rounds, base: ParamSpace, r: int) -> None:
    """After round ``r``: with ``--widen`` (and a round to follow) widen the bounds its posterior presses unless
    the run already decided after this round (:func:`~softsbi.workflows.widen.decide`); then, when round ``r + 1``
    draws in another prior, express the posterior its proposal truncates to in that prior's unit cube."""
    cfg, store = loop.cfg, loop.store
    if r + 1 >= cfg.rounds:
        return
    if cfg.widen and not any(int(w["after_round"]) == r for w in records(store.config)):
        post = loop.chain.posterior(len(loop.chain) - 1)
        samples = loop.space.from_unit(post.sample(4000, np.random.default_rng([cfg.seed, 99, r])))
        keep = {k: v for e in cfg.effects for k, v in registry().effect(e)().nominal().items()}
        if decide(store, loop.space, samples, r, keep) is not None:
            loop.cb.message(widening_sentence(records(store.config)[-1]))
    nxt = space_of_round(base, store.config, r + 1)
    if nxt != loop.space:
        q, count = loop.chain.qs[-1], loop.chain.counts[-1]
        loop.chain = PosteriorChain(nxt.dim, seed=cfg.seed)
        loop.chain.add_round(map_mixture(q, *unit_map(loop.space, nxt)), count)
        loop.space = nxt


def _best_fit(store: RunStore, post: RoundPosterior, space: ParamSpace, ctx: SimContext, executor: Any,
              cfg: FitConfig, hooks: FitCallbacks) -> dict[str, Any] | None:
    """``report.json``'s ``best_fit``: the best of the fit's simulations, after ``cfg.refine`` more by CMA-ES
    from the posterior (:mod:`~softsbi.workflows.bestfit`), with its rollout stored in the run."""
    frames = store.config.get("metric_frames")
    metric = store.config.get("metric", "chamfer_m")
    refined = None
    if cfg.refine > 0:
        before = best_stored(store, cfg.rounds, cfg.seed, frames)
        mean, cov = post.moments(20000, seed=cfg.seed + 20_000)
        have = len(store.read_rows(REFINE)[0]["status"]) if store.has(REFINE) else 0
        hooks.round_start(-2, cfg.rounds, max(cfg.refine - have, 0), cfg.refine)
        refined = refine(store, space, mean, cov, ctx, executor, cfg.refine, cfg.seed, cfg.rounds, frames,
                         progress=lambda d, n: hooks.simulation_done(-2, d, n), message=hooks.message)
        refined.update(requested=cfg.refine, start_mean=space.as_dict(space.from_unit(mean)),
                       best_before=None if before is None else before["score"])
    best = best_stored(store, cfg.rounds, cfg.seed, frames, cfg.refine)
    if best is None:
        return None
    stored = store_best_fit(store, best, space, ctx, executor, cfg.fixed)
    return {"theta": space.as_dict(best["theta"]), metric: best["score"],
            metric.replace("_m", "_per_frame_m").replace("_px", "_per_frame_px"): best["chamfer"].tolist(),
            "source": best["source"], "simulation": best["index"], "seed": best["seed"],
            "simulations_searched": best["simulations"], "rollout": "run.zarr/best_fit" if stored else None,
            "refine": refined}


def _open_store(out_dir: Path, recording: Recording, cfg: FitConfig, space: ParamSpace,
                callbacks: FitCallbacks) -> tuple[RunStore, float]:
    """Open the run store to resume it (checking the settings) or create it with the observed
    state; returns the store and the wall time already spent in it (s)."""
    config = _config_dict(cfg, recording, space)
    store_path = out_dir / "run.zarr"
    if RunStore.exists(store_path):
        store = RunStore.open(store_path)
        store.check_resumable(config, FitConfig.resume_keys(), RESUME_DEFAULTS, resume_identity)
        prev = store.config.get("wall_time_s", 0.0) or 0.0
        callbacks.message(_resume_message(store, prev))
        store.update_config(rounds=cfg.rounds)
        return store, prev
    x0 = observe_recording(cfg, recording)  # before creating the store: bad input leaves nothing behind
    store = RunStore.create(store_path, config)
    masks = hsv_mask(recording.images) if config["metric"] == "mask_chamfer_px" else None
    store.write_observed(x0, recording.scenario.gripper, recording.scenario.times, recording.dense,
                         recording.source, images=recording.images, masks=masks)
    store.update_config(rounds=cfg.rounds)
    return store, 0.0


def _repair_damaged(store: RunStore, callbacks: FitCallbacks) -> None:
    """Stored simulations whose chunks are missing or unreadable are named and simulated again
    from their stored parameters and seeds, never dropped or trained on; the rounds after the
    first damaged one are drawn again from its new posterior. Other groups with an unreadable array are
    computed again (a round's posterior, the evaluation, a calibration), or named when they cannot be
    (the observed data, a round's draws: :class:`SchemaError`)."""
    for name, why in store.damaged_groups().items():
        parts = name.split("/")
        if name == "observed" or (parts[0] == "rounds" and len(parts) == 2):
            raise SchemaError(f"'{store.path / name}' cannot be trusted ({why}); fit into a new --out folder")
        callbacks.message(f"'{store.path / name}' cannot be trusted ({why}); computing it again")
        if parts[0] != "rounds":
            store.remove_group(name)
        elif store.is_complete(int(parts[1])):  # (not when an earlier round's redo removed it)
            store.redo(int(parts[1]), [])  # retrain the round; the rounds after it are drawn again
    found = store.damaged()
    if found is None:
        return
    r, bad = found  # the earliest damaged round: the rounds after it are drawn again anyway
    rows = sorted(bad)
    reasons = sorted(set(bad.values()))
    dropped = store.redo(r, rows)
    callbacks.message(f"round {r + 1}: {len(rows)} stored simulations of {store.path} cannot be trusted "
                      f"(simulations {rows[:10]}{' ...' if len(rows) > 10 else ''}: {'; '.join(reasons)}); "
                      f"simulating them again from their stored seeds"
                      + (f", and drawing the {dropped} simulations of later rounds again" if dropped else ""))


def _retry_failed(store: RunStore, callbacks: FitCallbacks) -> None:
    """Make the stored failed simulations pending again (``fit --retry-failed``)."""
    redo = store.reset_failures()
    if redo is None:
        callbacks.message("no stored failed simulations to retry")
        return
    r, n_failed, n_dropped = redo
    callbacks.message(f"retrying {n_failed} failed simulations of round {r + 1}"
                      + (f"; the {n_dropped} simulations of later rounds were drawn from the old posterior of "
                         f"round {r + 1} and are drawn again" if n_dropped else ""))


def _resume_message(store: RunStore, spent_s: float) -> str:
    """What a resumed fit finds: complete rounds, the partly stored round, stored failed simulations (and the
    option that simulates them again), the time already spent."""
    done = store.completed_rounds()
    parts = [f"resuming run in {store.path} after round {len(done)}" if done else f"resuming run in {store.path}"]
    nxt = len(done)
    if store.is_begun(nxt):
        n = int(len(store.round_data(nxt)["status"]))
        stored = n - len(store.pending(nxt))
        parts.append(f"round {nxt + 1}: {stored} of {n} simulations already stored")
    failed = sum(int(np.sum((st != STATUS_OK) & (st != STATUS_PENDING)))
                 for st in (store.round_data(r, ("status",))["status"] for r in store.round_ids()))
    if failed:
        parts.append(f"{failed} stored simulations failed (after fixing what made them fail, --retry-failed "
                     f"simulates them again)")
    parts.append(f"{spent_s:.0f} s spent before")
    return "; ".join(parts)


class _Clock:
    """Wall time of a run over all its sessions (s), saved to the store's config as ``wall_time_s``
    at least every ``every`` seconds while simulating, so a killed session's time is not lost."""

    def __init__(self, store: RunStore, before: float, every: float = 15.0):
        self.store, self.before, self.every = store, before, every
        self.t0 = time.perf_counter()
        self.saved_at = self.t0

    def spent(self) -> float:
        return self.before + time.perf_counter() - self.t0

    def save(self, force: bool = False) -> float:
        now = time.perf_counter()
        if force or now - self.saved_at >= self.every:
            self.saved_at = now
            self.store.update_config(wall_time_s=self.spent())
        return self.spent()


def sim_bank(cfg: FitConfig) -> Path | None:
    """The simulation bank a fit's first round reads and fills (:mod:`~softsbi.workflows.bank`): ``cfg.sim_bank``
    ``"default"`` the user's (:func:`~softsbi.workflows.bank.default_bank`), ``"off"`` none, else that folder;
    none when ``$SOFTSBI_SIM_BANK`` is ``off``."""
    if cfg.sim_bank == "off" or not banks_enabled():
        return None
    return default_bank() if cfg.sim_bank == "default" else Path(cfg.sim_bank).expanduser()


def _sim_context(cfg: FitConfig, recording: Recording, store: RunStore, space: ParamSpace) -> SimContext:
    """What every simulation job of this fit needs: simulator, observer, the metric's reference."""
    observed = store.read_observed()
    metric = store.config.get("metric", "chamfer_m")
    return SimContext(backend=cfg.backend, backend_options=cfg.backend_options,
                      scenario=recording.scenario.to_json(), effects=list(cfg.effects), observer=cfg.observer,
                      observer_options=observer_options(cfg, recording.scenario), param_names=space.names,
                      fixed=dict(cfg.fixed), dense=observed.get("dense"), n_dense=cfg.n_dense,
                      ref_masks=observed.get("masks") if metric == "mask_chamfer_px" else None,
                      min_z=store.config.get("metric_min_z"), camera=store.config.get("metric_camera"))


class _Rounds:
    """The sequential rounds of one fit: draw the proposal, simulate, train, condition."""

    def __init__(self, cfg: FitConfig, store: RunStore, space: ParamSpace, ctx: SimContext, est_cls: type,
                 callbacks: FitCallbacks, clock: _Clock | None = None):
        self.cfg, self.store, self.space, self.ctx, self.est_cls, self.cb = cfg, store, space, ctx, est_cls, callbacks
        self.clock = clock
        self.sequential = bool(getattr(est_cls, "sequential", True))
        self.truncated = self.sequential and cfg.proposal == "truncated"
        self.chain = PosteriorChain(space.dim, seed=cfg.seed)
        self.summaries: list[dict[str, Any]] = []
        self.prior_stats: dict[str, Any] | None = None
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
        bank = sim_bank(cfg) if r == 0 else None  # the first round's draws depend on the task and the seed alone
        ctx = self.ctx if bank is None else replace(self.ctx, bank=str(bank))
        _simulate_missing(store, r, ctx, executor, self.cb, self.clock, self.sensor)
        d = store.round_data(r)
        stats = chamfer_stats(d["chamfer"], d["status"], store.config.get("metric_frames")) if self.scored else {}
        if r == 0:
            self.prior_stats = stats
        elif self.summaries:
            self.summaries[-1]["chamfer_posterior"] = stats  # round r draws from posterior r-1
        U, X, counts = _usable(store, r)
        if counts[r] == 0:
            reasons = sorted(set(store.round_attrs(r)["failures"].values()))
            effect_code = all(x.startswith(EffectFault.__name__) for x in reasons)  # an effect's code, not physics
            raise SoftsbiError(f"round {r + 1}: every simulation failed, e.g. {reasons[:3]}; "
                               + ("fix the effect's code named there" if effect_code else
                                  "narrow the prior bounds with --bounds or change backend options")
                               + f"; if the environment made them "
                               f"fail, fix it and re-run with --retry-failed (finished simulations are kept in "
                               f"{store.path})")
        q, info = self._train(r, U, X, counts)
        post = self._add_posterior(r, q, counts)
        try:
            mean_u, _ = post.moments(4000, seed=cfg.seed + r)
        except PosteriorError as exc:
            raise PosteriorError(f"round {r + 1}: estimator '{cfg.estimator}' conditioned on the measurement: {exc}. "
                                 f"Try another estimator (e.g. rkhs), more --sims-per-round or wider --bounds; "
                                 f"the finished simulations are kept in {store.path}") from exc
        self.summaries.append({"round": r, "simulations": int(len(d["status"])), "usable": counts[r],
                               "failed": int((d["status"] != STATUS_OK).sum()),
                               "bank_hits": int(store.round_attrs(r).get("bank_hits", 0)),
                               "chamfer_proposal": stats, "train": info, "mass_in_box": post.mass_in_box,
                               "posterior_mean": self.space.as_dict(self.space.from_unit(mean_u))})
        self.cb.round_end(r, self.summaries[-1])

    def _begin(self, r: int) -> None:
        """Draw round ``r``'s parameters from its proposal and store them (with their seeds)."""
        cfg, space = self.cfg, self.space
        proposal = None  # bulk estimators (sequential = False): every round draws from the prior
        if r > 0 and self.sequential:
            proposal = self.chain.posterior(len(self.chain) - 1)
            if self.truncated:
                proposal = TruncatedPrior(proposal, eps=cfg.truncation_eps, seed=cfg.seed + r)
        rng = np.random.default_rng([cfg.seed, r, 0])
        u = rng.random((cfg.sims_per_round, space.dim)) if proposal is None else proposal.sample(cfg.sims_per_round, rng)
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
                return round_posterior(store, r, cfg), store.round_attrs(r).get("info", {})
            except PosteriorDamaged as exc:  # train the round again from its intact simulations
                self.cb.message(f"{exc.problem}: training that round again from its stored simulations")
        opts = estimator_options(cfg, self.est_cls)
        est = self.est_cls(**opts)
        fr = slice(None) if cfg.frames is None else list(cfg.frames)
        n_sensor, kw = 0, {}
        if self.sensor is not None:  # one simulation, K more observations at other sensor parameters
            su, sx, sg = _sensor_pairs(store, r)
            n_sensor = len(su)
            if n_sensor:
                U, X = np.concatenate([U, su]), np.concatenate([X, sx])
                if "groups" in inspect.signature(est.fit).parameters:  # hold out whole simulations
                    kw["groups"] = np.concatenate([np.arange(len(U) - n_sensor), sg])
        info = est.fit(U.astype(np.float64), X[:, fr].astype(np.float64), seed=cfg.seed + r,
                       progress=lambda e, m, l, _r=r: self.cb.training_epoch(_r, e, m, l), **kw)
        q = est.posterior_at(self.x_obs[fr])  # the posterior at the observation x_o
        info = dict(info, n_train_total=int(len(U)), usable_per_round=counts, sensor_pairs=n_sensor,
                    **({"held_out_by_simulation": "groups" in kw} if n_sensor else {}))
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
    return est.posterior_at(store.read_observed()["x"][fr])


def _report(recording: Recording, cfg: FitConfig, space: ParamSpace, loop: _Rounds, ev_stats: dict[str, Any],
            samples: np.ndarray, wall: float, metric: str) -> dict[str, Any]:
    """``report.json``: settings, posterior summaries (physical units), Chamfer of prior and
    posterior-predictive rollouts, per-round summaries, and the truth when simulated."""
    summaries, prior_stats = loop.summaries, loop.prior_stats
    failed = sum(s["failed"] for s in summaries) + ev_stats.get("failed", 0)
    total = sum(s["simulations"] for s in summaries) + cfg.n_eval
    report = {
        "observed": recording.source,
        "backend": cfg.backend, "estimator": cfg.estimator, "effects": cfg.effects,
        "parameters": space.to_json(), "fixed": cfg.fixed,
        "rounds": cfg.rounds, "sims_per_round": cfg.sims_per_round, "simulations": total,
        "proposal": cfg.proposal if loop.sequential else "prior",
        "min_height_m": cfg.min_height, "frames": cfg.frames,
        "failed_simulations": failed,
        # simulations of the rounds read from the simulation bank instead of simulated (per round in per_round)
        "bank_hits": sum(s["bank_hits"] for s in summaries),
        "chamfer_prior_m": (prior_stats or {}).get("mean_m"),
        "chamfer_prior_std_m": (prior_stats or {}).get("std_m"),
        "chamfer_posterior_m": ev_stats.get("mean_m"),
        "chamfer_posterior_std_m": ev_stats.get("std_m"),
        "chamfer_posterior_n": ev_stats.get("n"),
        # the metric (issue 17): per frame, simulated and measured clouds seen through the fit's sensor
        # model; the headline values above are the mean over metric_frames
        # the sensor model stored with the run, which its simulations' per-frame metric used (_sim_context)
        "metric_min_z_m": loop.store.config.get("metric_min_z") if metric == "chamfer_m" else None,
        "metric_frames": cfg.frames if metric == "chamfer_m" else None, "metric_sensor": cfg.sensor,
        "chamfer_posterior_one_sided_m": ev_stats.get("one_sided_mean_m"),
        "chamfer_posterior_one_sided_std_m": ev_stats.get("one_sided_std_m"),
        "chamfer_prior_per_frame_m": (prior_stats or {}).get("per_frame_m"),
        "chamfer_posterior_per_frame_m": ev_stats.get("per_frame_m"),
        "chamfer_posterior_one_sided_per_frame_m": ev_stats.get("one_sided_per_frame_m"),
        "posterior_mean": space.as_dict(samples.mean(0)),
        "posterior_std": space.as_dict(samples.std(0)),
        "posterior_q05": space.as_dict(np.quantile(samples, 0.05, axis=0)),
        "posterior_q95": space.as_dict(np.quantile(samples, 0.95, axis=0)),
        "posterior_median": space.as_dict(np.median(samples, axis=0)),
        # width of the 90% interval over the prior's, in each parameter's own scale (log for log ones)
        "contraction": contraction(space, samples), "informed_max_width_ratio": INFORMED_MAX_RATIO,
        # parameters whose posterior piles up at a prior bound: a prior too narrow, or a misspecified model
        "posterior_at_bounds": bound_pressure(space, samples),
        "truth": recording.truth,
        "per_round": [{"round": s["round"], "usable": s["usable"], "failed": s["failed"], "bank_hits": s["bank_hits"],
                       "chamfer_posterior_m": (s.get("chamfer_posterior") or {}).get("mean_m"),
                       "chamfer_posterior_std_m": (s.get("chamfer_posterior") or {}).get("std_m"),
                       "mass_in_box": s["mass_in_box"], "train_seconds": s["train"].get("seconds"),
                       "posterior_mean": s["posterior_mean"]} for s in summaries],
        "wall_time_s": wall,
        "metric": metric,
    }
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
    if recording.truth:
        # an effect added by the fit but absent from the measurement is truly switched off
        truth = dict(recording.truth)
        for e in cfg.effects:
            for k, v in registry().effect(e)().nominal().items():
                truth.setdefault(k, v)
        report["truth"] = truth
        report["truth_in_90pct_interval"] = {
            n: bool(report["posterior_q05"][n] <= truth[n] <= report["posterior_q95"][n])
            for n in space.names if n in truth}
    return report


def _evaluate(store: RunStore, post: RoundPosterior, space: ParamSpace, ctx: SimContext, executor: Any,
              cfg: FitConfig, hooks: FitCallbacks) -> dict[str, Any]:
    """Rollouts at ``cfg.n_eval`` final-posterior samples (stored under ``evaluation/``)."""
    if store.has("evaluation"):
        arrays, attrs = store.read_group("evaluation")
        if attrs.get("rounds") == cfg.rounds and len(arrays["status"]) == cfg.n_eval:
            return chamfer_stats(arrays["chamfer"], arrays["status"], store.config.get("metric_frames"),
                                  arrays.get("chamfer_one_sided"))
    rng = np.random.default_rng([cfg.seed, 10_000 + cfg.rounds])
    u = post.sample(cfg.n_eval, rng)
    theta = space.from_unit(u)
    seeds = evaluation_seeds(cfg.seed, cfg.rounds, cfg.n_eval)
    T = len(ctx.scenario["times"])
    chamfer = np.full((cfg.n_eval, T), np.nan)
    one_sided = np.full((cfg.n_eval, T), np.nan)
    status = np.full(cfg.n_eval, STATUS_ERROR, np.uint8)
    hooks.round_start(-1, cfg.rounds, cfg.n_eval, cfg.n_eval)
    done = 0
    # the run's own bank: check, diagnose, compare and view re-simulate these rollouts first (RunView.sim_context)
    bank = str(store.path.parent / "sims.zarr") if banks_enabled() and ctx.ref_masks is None else None
    count = BankCount()
    for i, res in executor.map_unordered(simulate_job, list(zip(theta, seeds)), context=replace(ctx, bank=bank)):
        done += 1
        hooks.simulation_done(-1, done, cfg.n_eval)
        if isinstance(res, SoftsbiError):  # an environment fault: stop, nothing stored
            raise res
        if isinstance(res, BaseException):
            continue
        count.add(res.get("bank"))
        status[i] = res["status"]
        if res["chamfer"] is not None:
            chamfer[i] = res["chamfer"]
        if res.get("chamfer_one_sided") is not None:
            one_sided[i] = res["chamfer_one_sided"]
    _tell_bank(hooks, -1, count, cfg.n_eval, bank)
    arrays = {"theta": theta, "u": u, "status": status, "chamfer": chamfer}
    if ctx.ref_masks is None:
        arrays["chamfer_one_sided"] = one_sided
    store.write_group("evaluation", arrays,
                      attrs={"rounds": cfg.rounds, "what": "rollouts at final-posterior samples"},
                      units={"chamfer": "px" if ctx.ref_masks is not None else "m", "chamfer_one_sided": "m",
                             "theta": "physical"})
    return chamfer_stats(chamfer, status, store.config.get("metric_frames"), arrays.get("chamfer_one_sided"))
