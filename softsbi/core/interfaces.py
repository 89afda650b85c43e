"""Abstract interfaces every plugin implements.

Plugins (built-in or third-party) provide concrete subclasses through the pluggy hooks in
:mod:`softsbi.plugins.hookspecs`. Shapes and units in these docstrings are part of the
contract and are checked by :func:`softsbi.backends.conformance.check_simulator`.
"""
from __future__ import annotations

import inspect
import warnings
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, Callable, ClassVar, Iterable, Mapping, Sequence

import numpy as np

from softsbi.core.camera import Camera, RenderStyle
from softsbi.core.errors import DataError, ParameterError
from softsbi.core.types import Observation, ParamSpace, Rollout, Scenario
# the effect interface, defined beside these and re-exported here with them
from softsbi.core.effect import (EFFECT_KINDS, FORCE, MODEL_EDIT, OBSERVATION, Effect,  # noqa: F401
                                 VertexContext)



def batch_seeds(seed: "int | Sequence[int]", n: int) -> list[int]:
    """The ``n`` seeds of a batch of rollouts (:meth:`Simulator.simulate_batch`): ``seed + b`` for one int,
    else the ``n`` given.

    Raises:
        ParameterError: a sequence whose length is not ``n``.
    """
    if isinstance(seed, (int, np.integer)):
        return [int(seed) + b for b in range(n)]
    seeds = [int(s) for s in seed]
    if len(seeds) != n:
        raise ParameterError(f"simulate_batch got {len(seeds)} seeds for {n} parameter sets; give one seed per set "
                             f"or one int")
    return seeds


class Simulator(ABC):
    """A simulator backend.

    Class attributes:
        name: plugin name (``"mujoco-flex"``).
        scenarios: scenario names it can run.
        effects: effect names it can apply. A simulator with effects of its own that it applies
            by name lists them here (a tuple); the built-in backends derive it from the registry
            instead (every registered effect :meth:`supports` accepts).
        effect_kinds: the effect doors it implements (``"force"``, ``"model-edit"``,
            ``"observation"``; :class:`Effect`).

    Rendering is a template (:meth:`simulate_images`): a backend that can render supplies only
    frames, by overriding two hooks,

    * :meth:`_frame_renderer` ``(scenario, camera, style)`` -> a frame renderer: an object with
      ``edit(model)`` (called once with the engine's model description before it is built, for
      render-only additions such as a camera; may do nothing), ``__call__(k, state)`` (renders
      recorded frame ``k`` from the engine's state, called for ``k = 0 .. T-1`` in order and not
      after a failure), ``close()`` (releases GL contexts; always called), and the outputs
      ``rgb (T, H, W, 3)`` uint8, ``depth (T, H, W)`` float32 m, ``segmentation (T, H, W)``
      uint8, ``seconds`` and ``setup_seconds`` (float, s);
    * :meth:`_rollout` ``(scenario, theta, effects, seed, frames)``: the engine's one stepping
      loop (the same one :meth:`simulate` runs, so rendering never changes the vertices) calling
      ``frames`` as above when it is not None.
    """

    name: ClassVar[str]
    scenarios: ClassVar[tuple[str, ...]] = ()
    effects: ClassVar[tuple[str, ...]] = ()
    effect_kinds: ClassVar[tuple[str, ...]] = ()
    #: how many simulations a worker hands to one :meth:`simulate_batch` call (at most; an equal share of a
    #: phase's simulations per worker when that is fewer). 1: one :meth:`simulate` per job. A backend that
    #: steps several parameter sets together sets it (newton-cloth).
    batch_size: int = 1

    def check_installed(self) -> None:  # noqa: B027 - an optional hook: by default nothing to check
        """Refuse a machine that lacks an optional dependency this backend needs. A fit calls it before it creates
        its run directory, so that the run is refused in one line instead of being left begun with a backend that
        cannot simulate here. The default checks nothing (the backend needs only softsbi's own dependencies).

        Raises:
            DependencyMissing: the dependency is not installed (the message names the install command).
        """

    @classmethod
    def supports(cls, effect: "Effect | type[Effect]") -> str | None:
        """Whether this backend can apply ``effect``: None if it can, else what is missing (one phrase,
        e.g. ``"a force field (pybullet-massspring applies: observation)"``).

        An effect this backend lists by name in a plain ``effects`` tuple is its own (applied by name).
        Otherwise the backend must implement every kind the effect uses on it (:meth:`Effect.doors`).
        """
        eff = effect() if isinstance(effect, type) else effect
        own = inspect.getattr_static(cls, "effects", ())
        if isinstance(own, (tuple, list)) and eff.name in own:
            return None
        doors = eff.doors(cls.name)
        if not doors:
            return "any door (the effect has no force field, model edit or observation transform)"
        have = tuple(cls.effect_kinds)
        missing = []
        for d in doors:
            if d == MODEL_EDIT and cls.name not in eff.model_edits:
                missing.append(f"a model edit registered for '{cls.name}' (the effect has edits for: "
                               f"{', '.join(eff.model_edits)})")
            elif d not in have:
                what = {FORCE: "a force field", MODEL_EDIT: "model edits", OBSERVATION: "an observation transform"}[d]
                missing.append(f"{what} ({cls.name} applies: {', '.join(have) or 'none'})")
        return "; ".join(missing) or None

    @abstractmethod
    def param_space(self, scenario: Scenario) -> ParamSpace:
        """Nominal physical parameters for ``scenario``, with bounds that keep the engine stable."""

    @abstractmethod
    def simulate(self, scenario: Scenario, theta: Mapping[str, float],
                 effects: Sequence[str] = (), seed: int = 0) -> Rollout:
        """Roll ``scenario`` out at parameters ``theta`` (physical units).

        Args:
            scenario: the task; ``scenario.times`` fixes the recorded frames.
            theta: values for every parameter of ``param_space(scenario)`` plus those of each
                effect in ``effects``.
            effects: names of effects to switch on (each must be in ``self.effects``).
            seed: seeds any randomness (engines here are deterministic).

        Returns:
            A :class:`Rollout` with ``T = scenario.n_frames`` frames. Divergence or an
            implausible state is *returned* as ``status != 0`` with a reason, never raised,
            so a batch of simulations survives one bad sample.

        Raises:
            ParameterError: unknown/missing parameter, a value outside its physical limits
                (``ParamSpace.check(theta, within="limits")``: values beyond the declared prior but physical are
                simulated, so that a prior widened with ``--bounds`` can be fitted), unsupported effect.
            ValueError: a scenario this backend cannot run.
        """

    def simulate_batch(self, scenario: Scenario, thetas: Sequence[Mapping[str, float]], effects: Sequence[str] = (),
                       seed: "int | Sequence[int]" = 0) -> list[Rollout]:
        """Roll ``scenario`` out at B parameter sets: the B rollouts :meth:`simulate` would return, in order.
        This default calls :meth:`simulate` B times; a backend that steps them together overrides it.

        Args:
            thetas: B parameter mappings, as :meth:`simulate` takes one.
            seed: B seeds, one per rollout, or one int: rollout ``b`` uses ``seed + b`` (:func:`batch_seeds`).

        Raises:
            As :meth:`simulate`, for any of the B; ParameterError: B seeds do not match B thetas.
        """
        return [self.simulate(scenario, th, effects=effects, seed=s)
                for th, s in zip(thetas, batch_seeds(seed, len(thetas)))]

    def simulate_images(self, scenario: Scenario, theta: Mapping[str, float], camera: "Camera",
                        effects: Sequence[str] = (), seed: int = 0,
                        style: "RenderStyle | None" = None) -> Rollout:
        """Like :meth:`simulate`, and also render every recorded frame through ``camera``.

        The template of every backend: checks ``camera``/``style`` once, asks the backend for a
        frame renderer (:meth:`_frame_renderer`), runs the backend's own stepping loop
        (:meth:`_rollout`) with it as the per-frame hook, and closes it even when the loop raises.

        Args:
            camera: a :class:`~softsbi.core.camera.Camera` (exact pinhole intrinsics, OpenCV axes).
            style: :class:`~softsbi.core.camera.RenderStyle` colours and ``show_robot`` (default
                style if None).

        Returns:
            The rollout of :meth:`simulate` (identical vertices) whose ``rgb (T, H, W, 3)`` uint8,
            ``depth (T, H, W)`` float32 m (along the optical axis) and ``segmentation (T, H, W)``
            uint8 (``SEG_*`` labels: 0 table/background, 1 cloth/rope, 2 robot) are filled,
            ``H, W = camera.height, camera.width``; ``info["render_s"]`` is the time spent
            rendering, s (``info["render_setup_s"]`` of it once per rollout). A failed rollout
            (``status != 0``) has them None.

        Raises:
            NotImplementedError: this backend cannot render (no :meth:`_frame_renderer`).
            DataError: ``camera``/``style`` of the wrong type, or a mirrored camera (det R = -1).
            RenderingUnavailable: no off-screen OpenGL back-end works (backends that need one; the
                message names the fix).
            ValueError: unknown scenario. ParameterError: bad parameter or effect.
        """
        if type(self)._frame_renderer is Simulator._frame_renderer:
            raise NotImplementedError(f"backend '{self.name}' cannot render images; use a backend that "
                                      f"implements simulate_images (mujoco-flex, pybullet-massspring)")
        style = self._check_render_args(camera, style)
        frames = self._frame_renderer(scenario, camera, style)
        try:
            ro = self._rollout(scenario, theta, effects, seed, frames)
        finally:
            frames.close()
        if ro.ok:
            ro.rgb, ro.depth, ro.segmentation = frames.rgb, frames.depth, frames.segmentation
        ro.info["render_s"] = frames.seconds
        ro.info["render_setup_s"] = frames.setup_seconds
        return ro

    def _frame_renderer(self, scenario: Scenario, camera: "Camera", style: "RenderStyle") -> Any:
        """The per-frame renderer of :meth:`simulate_images` (see the class docstring); backends that
        render override it. ``style`` is already checked (never None)."""
        raise NotImplementedError(f"backend '{self.name}' cannot render images")

    def _rollout(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 seed: int = 0, frames: Any = None) -> Rollout:
        """The backend's stepping loop, rendering through ``frames`` when given (class docstring);
        backends that render override it together with :meth:`_frame_renderer`.

        Returns:
            the :class:`Rollout` of :meth:`simulate` (same vertices with or without ``frames``).

        Raises:
            NotImplementedError: the default (a backend overrode only :meth:`_frame_renderer`).
        """
        raise NotImplementedError(f"backend '{self.name}' defines _frame_renderer but not _rollout")

    @staticmethod
    def _check_render_args(camera: Any, style: Any) -> "RenderStyle":
        """Validate ``camera``/``style`` of :meth:`simulate_images`; returns the style (default if None).

        Raises:
            DataError: ``camera`` not a :class:`~softsbi.core.camera.Camera` or mirrored (det R < 0),
                ``style`` neither a :class:`~softsbi.core.camera.RenderStyle` nor None.
        """
        if not isinstance(camera, Camera):
            raise DataError(f"camera must be a softsbi.core.camera.Camera (e.g. scenario_camera(load_scenario('wipe'), 128)), "
                            f"got {type(camera).__name__}")
        if np.linalg.det(camera.R) < 0:
            raise DataError("camera.world_to_cam's 3x3 block is a reflection (det = -1), not a rotation: the "
                            "OpenCV axes x right, y down, z forward must form a right-handed frame (z = x cross y)")
        if style is None:
            return RenderStyle()
        if not isinstance(style, RenderStyle):
            raise DataError(f"style must be a softsbi.core.camera.RenderStyle or None, got {type(style).__name__}")
        return style


class Observer(ABC):
    """Maps a rollout to what a sensor would see (point clouds, keypoints).

    Class attributes:
        name: plugin name (``"pointcloud"``).
    """

    name: ClassVar[str]
    #: True for observers that need rendered frames: the loop then calls
    #: :meth:`Simulator.simulate_images` with the observer's ``camera`` and ``style``.
    needs_images: ClassVar[bool] = False

    @abstractmethod
    def observe(self, rollout: Rollout, rng: np.random.Generator) -> Observation:
        """Observation of a rollout: ``points (T, K, 3|2)``, ``gripper (T, 3)``."""


class KeypointExtractor(ABC):
    """Finds K keypoints in RGB images (supervised heatmaps, unsupervised Transporter...).

    Keypoints are pixel coordinates ``(u, v)`` = (column, row). Downstream they are treated as an
    unordered set per frame (the RKHS mean embedding), so an extractor need not keep identities.

    Class attributes:
        name: plugin name (``"heatmap"``).
        supervised: whether :meth:`fit` needs keypoint labels.
    """

    name: ClassVar[str]
    supervised: ClassVar[bool] = True

    def __init__(self, **config: Any):
        self.config = dict(config)

    @property
    @abstractmethod
    def trained(self) -> bool:
        """Whether :meth:`fit` or :meth:`load` has been called."""

    @property
    @abstractmethod
    def n_keypoints(self) -> int:
        """K."""

    @abstractmethod
    def fit(self, images: np.ndarray, keypoints: np.ndarray | None = None, masks: np.ndarray | None = None, *,
            seed: int = 0, progress: Callable[[int, int, float], None] | None = None) -> dict[str, Any]:
        """Train on ``images (N, H, W, 3)`` uint8 RGB, with ``keypoints (N, K, 2)`` px for supervised
        extractors and optional ``masks (N, H, W)`` bool (True = pixels to ignore in the loss, e.g. the
        robot). Returns training info (``epochs``, ``train_loss``, ``val_loss``, ``seconds``).

        Raises:
            ShapeError: images not ``(N, H, W, 3)`` uint8, or keypoints/masks not matching them.
        """

    @abstractmethod
    def predict(self, images: np.ndarray) -> np.ndarray:
        """Keypoints ``(N, K, 2)`` px ``(u, v)`` of ``images (N, H, W, 3)`` uint8 RGB (any size the
        extractor accepts; coordinates are in the given images' pixels).

        Raises:
            RuntimeError: called before :meth:`fit` / :meth:`load`.
            ShapeError: images of the wrong rank or channel count.
        """

    @abstractmethod
    def save(self, path: str | Path) -> None:
        """Write the trained extractor (weights and config) to ``path`` (a ``.pt`` file)."""

    @classmethod
    @abstractmethod
    def load(cls, path: str | Path) -> "KeypointExtractor":
        """Inverse of :meth:`save`.

        Raises:
            DataError: the file is missing or is not a checkpoint of this extractor.
        """


class PosteriorEstimator(ABC):
    """Learns a conditional density ``q(theta_unit | x)``: the posterior over the simulator parameters.

    ``theta_unit`` are the parameters ``theta`` mapped to the unit cube by
    :meth:`ParamSpace.to_unit`; ``x`` are states ``(N, T, 1 + K, 3)`` (per frame: gripper then K
    unordered points). The sequential loop applies the proposal correction; estimators only fit
    ``q`` (BayesSim, Ramos et al. RSS 2019, Sec. 3; Antonova et al. RA-L 2022, Sec. IV).

    Implementing one: subclass, implement :meth:`fit`, :meth:`posterior_at`, :meth:`state_dict` and
    :meth:`load_state_dict`, and register the class through the ``softsbi_estimators`` hook. The
    posterior may be any distribution over the unit-cube coordinates with ``dim``, ``sample(n, rng)``
    and ``log_prob(u)`` (:class:`~softsbi.core.distributions.Distribution`); the run store of
    ``softsbi fit`` keeps a Gaussian mixture as its arrays and any other posterior as the estimator's
    state, restored by plugin name and options (:meth:`~softsbi.core.store.RunStore.finish_round`).

    Renamed method (rule for estimators written before the rename): ``conditional(x_obs)`` is now
    :meth:`posterior_at`. The base class keeps :meth:`conditional` as a deprecated alias that calls
    :meth:`posterior_at`, and a subclass that still overrides ``conditional`` *instead of*
    :meth:`posterior_at` keeps working: the default :meth:`posterior_at` then calls that
    ``conditional``. A subclass overriding neither cannot be instantiated (``TypeError``, as for an
    abstract method).

    Class attributes:
        name: plugin name (``"rkhs"``).
        sequential: whether the estimator is meant for rounds (False for bulk baselines).
    """

    name: ClassVar[str]
    sequential: ClassVar[bool] = True

    def __new__(cls, *args: Any, **kwargs: Any):
        if not (cls._overrides("posterior_at") or cls._overrides("conditional")):
            raise TypeError(f"Can't instantiate {cls.__name__}: a PosteriorEstimator must implement "
                            f"posterior_at(x_obs)")
        return super().__new__(cls)

    @classmethod
    def _overrides(cls, method: str) -> bool:
        """Whether ``cls`` (or a base between it and :class:`PosteriorEstimator`) defines ``method``."""
        return getattr(cls, method) is not getattr(PosteriorEstimator, method)

    def __init__(self, **config: Any):
        self.config = dict(config)

    @abstractmethod
    def fit(self, theta_unit: np.ndarray, x: np.ndarray, *, seed: int = 0,
            progress: Callable[[int, int, float], None] | None = None) -> dict[str, Any]:
        """Train ``q`` on simulations.

        Args:
            theta_unit: ``(N, D)`` parameters in the unit cube (:meth:`ParamSpace.to_unit`).
            x: ``(N, T, 1+K, 3)`` states in metres.
            seed: seeds every random choice of the fit (same seed, same estimator).
            progress: ``progress(epoch, max_epochs, loss)``, called once per epoch when given.

        An estimator whose ``fit`` also takes ``groups`` (``(N,)`` labels of samples observed from one
        simulation, ``FitConfig.sensor_draws``) is given them, so that a validation split can hold out whole
        simulations; the built-in neural estimators do.

        Returns:
            Training info (``epochs``, ``train_loss``, ``val_loss``, ``seconds``).

        Raises:
            ShapeError: shapes not as above. DataError: non-finite values or too few simulations.
        """

    def posterior_at(self, x_obs: np.ndarray) -> Any:
        """The posterior ``q(theta_unit | x_o)`` at one observation ``x_o = x_obs`` ``(T, 1+K, 3)`` over the
        (unbounded) unit-cube coordinates: a :class:`~softsbi.core.distributions.MixtureOfGaussians`, or any
        distribution with ``dim``, ``sample(n, rng)`` and ``log_prob(u)`` (e.g. a normalising flow).

        Subclasses implement this. The default exists only for estimators written before the rename:
        it calls their overridden :meth:`conditional`.

        Raises:
            RuntimeError: called before :meth:`fit`.
            NotImplementedError: the subclass overrides neither this nor :meth:`conditional`.
        """
        if type(self)._overrides("conditional"):
            return self.conditional(x_obs)
        raise NotImplementedError(f"{type(self).__name__} must implement posterior_at(x_obs)")

    def conditional(self, x_obs: np.ndarray) -> Any:
        """Deprecated alias of :meth:`posterior_at` (same arguments, result and errors).

        Warns:
            DeprecationWarning: always; call :meth:`posterior_at`.
        """
        warnings.warn(f"{type(self).__name__}.conditional(x_obs) is deprecated; use posterior_at(x_obs)",
                      DeprecationWarning, stacklevel=2)
        return self.posterior_at(x_obs)

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to restore the fitted estimator: NumPy arrays, numbers, strings, None, and
        dicts and lists of them (the run store keeps it for a posterior that is not a Gaussian mixture;
        :meth:`load_state_dict` then receives the arrays as NumPy arrays and tuples as lists)."""
        return {}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:  # noqa: B027 - optional: stateless by default
        """Inverse of :meth:`state_dict`."""


class Executor(ABC):
    """Runs independent jobs (simulations) and yields results as they finish.

    Class attributes:
        name: plugin name (``"local"``).
    """

    name: ClassVar[str]

    @abstractmethod
    def map_unordered(self, fn: Callable[[Any, Any], Any], items: Sequence[Any],
                      context: Any = None) -> Iterable[tuple[int, Any]]:
        """Yield ``(index, fn(context, items[index]))`` in completion order.

        ``context`` (large, read-only data such as the observed clouds) is shipped to each
        worker once, not once per item. ``fn`` must be a picklable module-level function.
        If ``fn`` raises, the exception object is yielded in place of the result, so one
        failed job never stops the batch.
        """

    def close(self) -> None:  # noqa: B027 - optional: an executor without workers has nothing to release
        """Release workers."""
