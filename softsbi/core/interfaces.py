"""Abstract interfaces every plugin implements.

Plugins (built-in or third-party) provide concrete subclasses through the pluggy hooks in
:mod:`softsbi.plugins.hookspecs`. Shapes and units in these docstrings are part of the
contract and are checked by :func:`softsbi.core.checks.check_simulator`.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, ClassVar, Iterable, Mapping, Sequence

import numpy as np

from .distributions import MixtureOfGaussians
from .types import Observation, ParamSpace, Rollout, Scenario

if TYPE_CHECKING:
    from .camera import Camera, RenderStyle


class Effect(ABC):
    """A named physical effect that a nominal model may lack (air drag, wind, slip...).

    An effect contributes its own parameters (physical units) and is *applied by a backend*:
    the backend lists the effect names it supports in ``Simulator.effects`` and reads the
    effect's parameter values from the ``theta`` mapping passed to ``simulate``.

    Class attributes:
        name: identifier used with ``--effect``.
        description: one line.
        backends: names of the simulators that can apply it.
    """

    name: ClassVar[str]
    description: ClassVar[str] = ""
    backends: ClassVar[tuple[str, ...]] = ()

    @abstractmethod
    def param_space(self) -> ParamSpace:
        """The effect's own parameters with prior bounds and units."""

    def nominal(self) -> dict[str, float]:
        """Parameter values that switch the effect off (default: the lower bounds)."""
        return {p.name: p.low for p in self.param_space()}


class Simulator(ABC):
    """A simulator backend.

    Class attributes:
        name: plugin name (``"mujoco-flex"``).
        scenarios: scenario names it can run.
        effects: effect names it can apply.
    """

    name: ClassVar[str]
    scenarios: ClassVar[tuple[str, ...]] = ()
    effects: ClassVar[tuple[str, ...]] = ()

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
            ParameterError: unknown/missing parameter, value out of bounds, unsupported effect.
            ValueError: a scenario this backend cannot run.
        """


    def simulate_images(self, scenario: Scenario, theta: Mapping[str, float], camera: "Camera",
                        effects: Sequence[str] = (), seed: int = 0,
                        style: "RenderStyle | None" = None) -> Rollout:
        """Like :meth:`simulate`, and also render every recorded frame through ``camera``.

        Returns:
            A :class:`Rollout` whose ``rgb (T, H, W, 3)`` uint8, ``depth (T, H, W)`` float32 m
            (along the optical axis) and ``segmentation (T, H, W)`` uint8 (``SEG_*`` labels) are
            filled, ``H, W = camera.height, camera.width``. A failed rollout may leave them None.

        Raises:
            NotImplementedError: this backend cannot render (the default).
        """
        raise NotImplementedError(f"backend '{self.name}' cannot render images; use a backend that "
                                  f"implements simulate_images (mujoco-flex, pybullet-fem)")


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
    """Learns a conditional density ``q(u | x)`` over the unit-cube parameters.

    ``u`` are parameters mapped by :meth:`ParamSpace.to_unit`; ``x`` are states
    ``(N, T, 1 + K, 3)`` (per frame: gripper then K unordered points). The sequential loop
    applies the proposal correction; estimators only fit ``q``.

    Class attributes:
        name: plugin name (``"rkhs"``).
        sequential: whether the estimator is meant for rounds (False for bulk baselines).
    """

    name: ClassVar[str]
    sequential: ClassVar[bool] = True

    def __init__(self, **config: Any):
        self.config = dict(config)

    @abstractmethod
    def fit(self, u: np.ndarray, x: np.ndarray, *, seed: int = 0,
            progress: Callable[[int, int, float], None] | None = None) -> dict[str, Any]:
        """Train on ``u (N, D)`` and ``x (N, T, 1+K, 3)``; returns training info
        (``epochs``, ``train_loss``, ``val_loss``, ``seconds``). ``progress(epoch, max_epochs, loss)``
        is called once per epoch when given."""

    @abstractmethod
    def conditional(self, x_obs: np.ndarray) -> MixtureOfGaussians:
        """``q(u | x_obs)`` as a Gaussian mixture over the (unbounded) unit-cube coordinates.

        Raises:
            RuntimeError: called before :meth:`fit`.
        """

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to restore the fitted estimator (for the run store)."""
        return {}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
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

    def close(self) -> None:
        """Release workers."""
