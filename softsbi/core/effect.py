"""The effect interface: a physical or sensor effect with its own parameters, acting on a simulation through doors
the backends understand without knowing it by name (a force field, a model edit, an observation transform).

Re-exported by :mod:`softsbi.core.interfaces` with the other plugin interfaces.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import numpy as np

from softsbi.core.types import ParamSpace, Rollout


#: the ways an effect can act on a simulation (see :class:`Effect`); a backend lists those it
#: supports in ``Simulator.effect_kinds``
FORCE, MODEL_EDIT, OBSERVATION = "force", "model-edit", "observation"
EFFECT_KINDS = (FORCE, MODEL_EDIT, OBSERVATION)


@dataclass(frozen=True)
class VertexContext:
    """What a force field may know about the simulated object besides its state (engine-neutral).

    Attributes:
        mass: ``(N,)`` kg, the mass each vertex carries (the engine's own lumped masses).
        area: ``(N,)`` m^2, the surface patch each vertex stands for (cloth: spacing^2; rope:
            spacing x diameter), e.g. for drag per area.
        x0: ``(N, 3)`` m, vertex positions at t = 0 (the cloth lies flat on the table).
        table_z: height of the table top, m (world frame, z up).
        spacing: rest distance between neighbouring vertices, m.
        shape: vertex layout: ``(n, n)`` for a cloth grid (vertex ``i * n + j``, x-major,
            :func:`softsbi.backends.common.grid_faces`), ``(n,)`` for a rope (vertex 0 grasped).
        grasped: indices of the grasped vertices (one per handle, in the scenario's order of handles).
        gravity: ``(3,)`` m/s^2.
        handles: ``(H, 3)`` m, each handle's current position (its grasp target at this step), in the scenario's
            order of handles (:attr:`~softsbi.core.types.Scenario.handles`, names in ``handle_names``); the
            backend updates it in place before every call of :meth:`Effect.force`, so read it there, not once.
            ``(0, 3)`` where the backend does not say.
        handle_names: the handles' names, as ``handles``.
        corners: vertex indices of a grid cloth's corners 0-3 (:func:`softsbi.backends.common.grid_corners`:
            ``(0, 0)``, ``(0, n-1)``, ``(n-1, n-1)``, ``(n-1, 0)``; corner 0 is the placed one); ``()`` for a rope
            or a mesh cloth.
    """

    mass: np.ndarray
    area: np.ndarray
    x0: np.ndarray
    table_z: float
    spacing: float
    shape: tuple[int, ...]
    grasped: tuple[int, ...] = (0,)
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    handles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    handle_names: tuple[str, ...] = ()
    corners: tuple[int, ...] = ()

    @property
    def edges(self) -> np.ndarray:
        """``(N,)`` bool: vertices on the border of a cloth grid (both ends of a rope)."""
        n = int(np.prod(self.shape))
        out = np.zeros(n, dtype=bool)
        if len(self.shape) == 2:
            g = np.zeros(self.shape, dtype=bool)
            g[0, :] = g[-1, :] = g[:, 0] = g[:, -1] = True
            out[:] = g.ravel()
        else:
            out[[0, n - 1]] = True
        return out


class Effect(ABC):
    """A physical or sensor effect that a nominal model may lack (air drag, wind, a soft grasp, a
    calibration offset...), with its own parameters (physical units) and ways to act that backends
    understand *without knowing the effect by name* (the effect door, docs/design.md, "Interfaces"):

    * a **force field** (kind ``"force"``): override :meth:`force`; the backend adds the returned
      ``(N, 3)`` newtons to the object's vertices before every physics step (mujoco-flex:
      ``xfrc_applied`` of the flex vertex bodies). Engine-neutral: every backend with ``"force"``
      in ``Simulator.effect_kinds`` applies it.
    * a **model edit** for a named backend (kind ``"model-edit"``): list the backend in
      ``model_edits`` and override :meth:`edit_model`, which changes the backend's model description
      before it is built (mujoco-flex: the dict of :func:`softsbi.backends.mujoco_flex.build_spec`).
      On that backend the edit is used *in place of* the force field (it is the engine's faithful
      version of the same physics, e.g. MuJoCo's fluid model).
    * an **observation transform** (kind ``"observation"``, sensor effects): override
      :meth:`observe`, which maps the finished rollout to what the sensor reports (offset, noise,
      time shift), with a seeded random generator.

    A backend supports an effect iff it supports every kind the effect uses on it
    (:meth:`doors`, :meth:`Simulator.supports`).

    Class attributes:
        name: identifier used with ``--effect``.
        description: one line.
        backends: simulators the effect was written and tested for (informational; support is
            decided by the kinds, not by this list).
        kind: ``"physics"`` (acts on the motion) or ``"sensor"`` (acts on the observation only),
            so verdicts can separate the two.
        generic: True for the generic force terms (constant, linear/quadratic in velocity, linear in
            height) that describe residuals no named effect explains; they are not ordinary
            diagnosis candidates.
        model_edits: backend names for which :meth:`edit_model` is implemented.
        objects: the object kinds (a scenario's ``object.kind``: ``"cloth"``, ``"rope"``) the effect can act on
            (None: every kind); ``diagnose`` and ``check`` leave an effect out of the default candidate family of a task whose object
            it cannot act on (:func:`~softsbi.workflows.criticism.screening.candidate_effects`), and naming it
            there is refused.
        estimator_options: options this effect asks of the posterior estimator so that its parameters can
            be identified from the observations (e.g. point noise: ``{"frame_thickness": True}``, a summary
            that sees centimetre noise). A fit whose model has the effect passes them to an estimator that
            has the option (:func:`softsbi.workflows.fit.run.estimator_options`); the user's own
            ``estimator_options`` win.
    """

    name: ClassVar[str]
    description: ClassVar[str] = ""
    backends: ClassVar[tuple[str, ...]] = ()
    kind: ClassVar[str] = "physics"
    generic: ClassVar[bool] = False
    model_edits: ClassVar[tuple[str, ...]] = ()
    objects: ClassVar[tuple[str, ...] | None] = None
    estimator_options: ClassVar[Mapping[str, Any]] = {}

    @abstractmethod
    def param_space(self) -> ParamSpace:
        """The effect's own parameters with prior bounds and units."""

    def nominal(self) -> dict[str, float]:
        """Parameter values that switch the effect off (default: the lower bounds)."""
        return {p.name: p.low for p in self.param_space()}

    # -- the three doors --------------------------------------------------------------------
    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        """Per-vertex force field (override to use the ``"force"`` door).

        Args:
            x: ``(N, 3)`` vertex positions, m (world/scenario frame, z up).
            v: ``(N, 3)`` vertex velocities, m/s.
            t: time since the start of the rollout, s.
            theta: this effect's own parameters (physical units).
            ctx: masses, areas, rest positions, table height, layout, the handles' current positions and the
                cloth's corner vertices (:class:`VertexContext`).

        Returns:
            ``(N, 3)`` forces in newtons, applied at the vertices until the next step.
        """
        raise NotImplementedError(f"effect '{self.name}' has no force field")

    def edit_model(self, backend: str, model: Any, theta: Mapping[str, float], ctx: Mapping[str, Any]) -> None:
        """Edit ``backend``'s model description in place before it is built (override together with
        ``model_edits``).

        Args:
            backend: the simulator's name (one of ``model_edits``).
            model: the backend's model description (mujoco-flex: the spec dict of ``build_spec``).
            theta: this effect's own parameters (physical units).
            ctx: backend facts (mujoco-flex: ``grid``, ``spacing`` m, ``vertex_mass`` kg, ``timestep`` s).
        """
        raise NotImplementedError(f"effect '{self.name}' has no model edit for '{backend}'")

    def observe(self, rollout: Rollout, theta: Mapping[str, float], rng: np.random.Generator) -> Rollout:
        """Observation transform (override to use the ``"observation"`` door): what the sensor reports
        of a finished, successful rollout.

        Args:
            rollout: the simulated rollout (not modified).
            theta: this effect's own parameters (physical units).
            rng: seeded by the simulation's seed.

        Returns:
            A new :class:`Rollout` with the same frames and vertex count (``gripper``, the commanded
            path, is left as it is). It may move the vertices (what the sensor reports of them) and may
            set ``info[INFO_MIN_VISIBLE_Z]`` (:data:`~softsbi.core.types.INFO_MIN_VISIBLE_Z`, m): points
            at or below that height are then not seen by the observers and the metric.
        """
        raise NotImplementedError(f"effect '{self.name}' has no observation transform")

    @classmethod
    def _overrides(cls, method: str) -> bool:
        return getattr(cls, method) is not getattr(Effect, method)

    def doors(self, backend: str) -> tuple[str, ...]:
        """The kinds this effect uses on ``backend``: ``"model-edit"`` if it registered one for that
        backend, else ``"force"`` if it has a force field, else ``"model-edit"`` if it has edits only for
        other backends (which ``backend`` then lacks); plus ``"observation"`` if it has a transform.
        Empty: the effect has no door at all."""
        out: list[str] = []
        if backend in self.model_edits:
            out.append(MODEL_EDIT)
        elif self._overrides("force"):
            out.append(FORCE)
        elif self.model_edits:
            out.append(MODEL_EDIT)
        if self._overrides("observe"):
            out.append(OBSERVATION)
        return tuple(out)

    def own(self, theta: Mapping[str, float]) -> dict[str, float]:
        """This effect's parameters taken from a full ``theta`` mapping.

        Raises:
            KeyError: one of them is missing (backends check ``theta`` first).
        """
        return {n: float(theta[n]) for n in self.param_space().names}
