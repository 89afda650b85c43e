"""Data model of softsbi: parameter spaces, scenarios, rollouts and observations.

Conventions (part of the public contract):

* lengths in metres, times in seconds, masses in kilograms;
* the world frame is right-handed with z up and the table top at ``Scenario.table_z``;
* arrays are NumPy ``float64`` unless stated otherwise.

This module imports no simulator and no torch.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import PurePath
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from softsbi.core.errors import ParameterError, ShapeError, closest


def unit_suffix(unit: str | None) -> str:
    """``" m"`` for a value's unit in running text, ``""`` for a dimensionless one (``"1"``, ``""`` or None)."""
    return "" if unit in (None, "", "1") else f" {unit}"


@dataclass(frozen=True)
class Param:
    """One physical parameter.

    Attributes:
        name: identifier used on the command line and in stores (e.g. ``"bend"``).
        low, high: bounds of the uniform prior, in ``unit``; ``low < high``.
        unit: physical unit as text (e.g. ``"Pa"``, ``"m"``, ``"1"`` for dimensionless).
        log: if True the prior is log-uniform and inference works on ``log(value)``;
            requires ``low > 0``.
        description: one line for humans.
        limits: ``(lowest, highest)`` values that are physically meaningful (a simulator accepts any value
            inside them), wider than or equal to the prior box; the prior bounds are a default guess that the
            user widens with ``--bounds`` up to these. None: ``(0, inf)`` for a log-scaled parameter or one
            whose prior starts at or above 0 (a stiffness, a friction coefficient, a noise level), else
            ``(-inf, inf)`` (a wind component, an offset). See :attr:`physical_limits`.

    Raises:
        ParameterError: ``low >= high``, a log-scaled parameter with ``low <= 0``, or limits that do not
            contain ``[low, high]``.
    """

    name: str
    low: float
    high: float
    unit: str = "1"
    log: bool = False
    description: str = ""
    limits: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not self.low < self.high:
            raise ParameterError(f"parameter '{self.name}': low ({self.low}) must be < high ({self.high})")
        if self.log and self.low <= 0:
            raise ParameterError(f"parameter '{self.name}' is log-scaled, so low must be > 0 (got {self.low})")
        if self.limits is not None:
            object.__setattr__(self, "limits", (float(self.limits[0]), float(self.limits[1])))
        lo, hi = self.physical_limits
        if not (lo <= self.low and self.high <= hi):
            u = unit_suffix(self.unit)
            raise ParameterError(f"parameter '{self.name}': prior bounds [{self.low:g}, {self.high:g}]{u} "
                                 f"must lie within its physical limits [{lo:g}, {hi:g}]{u}")

    @property
    def physical_limits(self) -> tuple[float, float]:
        """``(lowest, highest)`` physically meaningful value: :attr:`limits`, or the default described there."""
        if self.limits is not None:
            return self.limits
        return (0.0, math.inf) if (self.log or self.low >= 0) else (-math.inf, math.inf)

    def summary(self) -> dict[str, Any]:
        """The parameter as ``softsbi params`` and ``softsbi plugins`` list it (JSON-able): ``name``, ``unit``,
        ``prior`` ``[low, high]``, ``scale`` (``"log"``: log-uniform prior, inferred as ``log(value)``;
        ``"linear"``: uniform), the physical ``limits`` (:attr:`physical_limits`, an infinite end as None) and
        the ``description``."""
        lo, hi = self.physical_limits
        return {"name": self.name, "unit": self.unit, "prior": [self.low, self.high],
                "scale": "log" if self.log else "linear",
                "limits": [None if math.isinf(lo) else lo, None if math.isinf(hi) else hi],
                "description": self.description}


class ParamSpace:
    """An ordered set of :class:`Param` with a uniform (or log-uniform) box prior.

    Inference happens in the *unit cube*: ``u = (t(theta) - t(low)) / (t(high) - t(low))``
    with ``t = log`` for log-scaled parameters and identity otherwise, so the prior is
    uniform on ``[0, 1]^D``.

    Raises:
        ParameterError: duplicate names.
    """

    def __init__(self, params: Sequence[Param]):
        names = [p.name for p in params]
        if len(set(names)) != len(names):
            raise ParameterError(f"duplicate parameter names in {names}")
        self.params: tuple[Param, ...] = tuple(params)

    # -- basic access -------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        return [p.name for p in self.params]

    @property
    def dim(self) -> int:
        return len(self.params)

    def __len__(self) -> int:
        return self.dim

    def __iter__(self):
        return iter(self.params)

    def __getitem__(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise ParameterError(f"unknown parameter '{name}'.{closest(name, self.names)} "
                             f"Valid parameters: {', '.join(self.names)}")

    def __add__(self, other: "ParamSpace") -> "ParamSpace":
        return ParamSpace(list(self.params) + list(other.params))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ParamSpace) and self.params == other.params

    def subset(self, names: Iterable[str]) -> "ParamSpace":
        return ParamSpace([self[n] for n in names])

    def with_bounds(self, overrides: Mapping[str, tuple[float, float]]) -> "ParamSpace":
        """Return a copy with some prior bounds replaced: ``{"bend": (1e-6, 1e-3)}``. The new bounds may be
        wider than the declared ones, up to the parameter's :attr:`Param.physical_limits`.

        Raises:
            ParameterError: an unknown name, ``low >= high``, or bounds outside the physical limits.
        """
        for n in overrides:
            self[n]  # raises ParameterError for unknown names
        out = []
        for p in self.params:
            if p.name in overrides:
                lo, hi = overrides[p.name]
                if p.limits is None:  # keep the declared default's limits, not the new bounds' default
                    p = dataclasses.replace(p, limits=p.physical_limits)
                p = dataclasses.replace(p, low=float(lo), high=float(hi))
            out.append(p)
        return ParamSpace(out)

    # -- transforms -----------------------------------------------------------------
    def _t(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        lo = np.array([math.log(p.low) if p.log else p.low for p in self.params])
        hi = np.array([math.log(p.high) if p.log else p.high for p in self.params])
        lg = np.array([p.log for p in self.params])
        return lo, hi, lg

    def to_unit(self, theta: np.ndarray) -> np.ndarray:
        """Map physical values ``(..., D)`` to the unit cube ``(..., D)``."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape[-1] != self.dim:
            raise ShapeError(f"theta has {theta.shape[-1]} columns, parameter space has {self.dim} ({self.names})")
        lo, hi, lg = self._t()
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(lg, np.log(np.where(lg, theta, 1.0)), theta)
        return (t - lo) / (hi - lo)

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Map unit-cube coordinates ``(..., D)`` to physical values ``(..., D)``."""
        u = np.asarray(u, dtype=float)
        if u.shape[-1] != self.dim:
            raise ShapeError(f"u has {u.shape[-1]} columns, parameter space has {self.dim}")
        lo, hi, lg = self._t()
        t = lo + u * (hi - lo)
        out = np.where(lg, np.exp(t), t)
        # exp(log(x)) can land one rounding step outside a log bound: clip points of the box
        plo = np.array([p.low for p in self.params])
        phi = np.array([p.high for p in self.params])
        inside = (u >= 0) & (u <= 1)
        return np.where(inside, np.clip(out, plo, phi), out)

    def log_det_jacobian(self, theta: np.ndarray) -> np.ndarray:
        """``log |du/dtheta|`` summed over dimensions, shape ``theta.shape[:-1]``.

        Converts a density over the unit cube into a density over physical values:
        ``log p(theta) = log p(u) + log_det_jacobian(theta)``.
        """
        theta = np.asarray(theta, dtype=float)
        lo, hi, lg = self._t()
        per = np.where(lg, -np.log(np.abs(np.where(lg, theta, 1.0))), 0.0) - np.log(hi - lo)
        return per.sum(-1)

    def contains(self, theta: np.ndarray) -> np.ndarray:
        """Boolean ``(...)``: whether each row lies inside the prior box (inclusive)."""
        u = self.to_unit(theta)
        return np.all((u >= -1e-12) & (u <= 1 + 1e-12), axis=-1)

    def sample_prior(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws ``(n, D)`` from the (log-)uniform prior, physical units."""
        return self.from_unit(rng.random((n, self.dim)))

    def check(self, theta: Mapping[str, float], *, allow_missing: bool = False,
              within: str = "prior") -> dict[str, float]:
        """Validate a name->value mapping: known names, finite values inside the prior bounds
        (``within="prior"``) or inside the physical limits (``within="limits"``: what a simulator accepts, so
        that a prior widened with ``--bounds`` beyond the declared one can be simulated).

        Raises:
            ParameterError: unknown name (with the closest valid name), a value that is not a number, a value
                outside ``[low, high]`` (or the limits) or not finite, or a missing name (unless ``allow_missing``).
            ValueError: ``within`` not ``"prior"`` or ``"limits"``.
        """
        if within not in ("prior", "limits"):
            raise ValueError(f"within must be 'prior' or 'limits', got {within!r}")
        out: dict[str, float] = {}
        for k, v in theta.items():
            p = self[k]
            try:
                v = float(v)
            except (TypeError, ValueError):
                u = unit_suffix(p.unit)
                raise ParameterError(f"parameter '{k}' = {v!r} is not a number; give a number{' in' + u if u else ''}, "
                                     f"e.g. {k}={p.low:g}") from None
            lo, hi = (p.low, p.high) if within == "prior" else p.physical_limits
            if not math.isfinite(v) or v < lo or v > hi:
                what = "bounds" if within == "prior" else "physical limits"
                u = unit_suffix(p.unit)
                raise ParameterError(
                    f"parameter '{k}' = {v:g}{u} is outside its {what} [{lo:g}, {hi:g}]{u}; "
                    f"choose a value inside them")
            out[k] = v
        if not allow_missing:
            missing = [n for n in self.names if n not in out]
            if missing:
                raise ParameterError(f"missing values for parameters {missing}; give all of {self.names}")
        return out

    def as_dict(self, row: np.ndarray) -> dict[str, float]:
        """``(D,)`` array -> ``{name: value}``."""
        return {n: float(v) for n, v in zip(self.names, np.asarray(row).ravel())}

    def as_array(self, theta: Mapping[str, float]) -> np.ndarray:
        """``{name: value}`` -> ``(D,)`` array in this space's order."""
        return np.array([float(theta[n]) for n in self.names])

    def midpoint(self) -> dict[str, float]:
        """Centre of the prior box (geometric centre for log-scaled parameters)."""
        return self.as_dict(self.from_unit(np.full(self.dim, 0.5)))

    def to_json(self) -> list[dict[str, Any]]:
        """The parameters as JSON-able dicts (``limits`` only where set, as ``[low, high]``; infinite ends as
        None)."""
        out = []
        for p in self.params:
            d = dataclasses.asdict(p)
            if p.limits is None:
                d.pop("limits")
            else:
                d["limits"] = [None if math.isinf(v) else v for v in p.limits]
            out.append(d)
        return out

    @classmethod
    def from_json(cls, data: Sequence[Mapping[str, Any]]) -> "ParamSpace":
        def limits(v):
            return None if v is None else (-math.inf if v[0] is None else v[0], math.inf if v[1] is None else v[1])
        return cls([Param(**{**d, "limits": limits(d.get("limits"))}) for d in data])

    def __repr__(self) -> str:
        inner = ", ".join(f"{p.name}[{p.low:g},{p.high:g}]{p.unit}{'(log)' if p.log else ''}" for p in self.params)
        return f"ParamSpace({inner})"


@dataclass
class Handle:
    """One grasp of the object: a vertex held by the robot (pinned, or following a path).

    Attributes:
        name: label (e.g. ``"grip"``, ``"held_corner"``).
        grasp: which vertex: ``{"corner": k}`` (grid cloth, :func:`~softsbi.backends.common.grid_corners`
            order, 0 = the placed corner), ``{"end": k}`` (rope: 0 = the start end, 1 = the far end),
            ``{"vertex": i}`` (mesh cloth: index into the mesh) or ``{"point": [x, y, z]}`` (the rest
            vertex nearest to this point of the scenario frame, m).
        path: ``(T, 3)`` m, the commanded positions at the scenario's frame times, or None for a pinned
            handle (held where the vertex rests). Backends shift a path by a constant so it starts on
            the grasped vertex, and interpolate it linearly between frames.
    """

    name: str
    grasp: dict[str, Any]
    path: np.ndarray | None = None

    @property
    def pinned(self) -> bool:
        return self.path is None

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "grasp": jsonable(self.grasp),
                "path": None if self.path is None else np.asarray(self.path).tolist()}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "Handle":
        return cls(name=str(d["name"]), grasp=dict(d["grasp"]),
                   path=None if d.get("path") is None else np.asarray(d["path"], dtype=float))


#: the planes a scenario's 2-D figures can show (:attr:`Scenario.view`)
VIEWS = ("xz", "yz", "xy")


@dataclass
class Scenario:
    """A manipulation task: what the robot does to the object, independent of the engine.

    Scenarios are data: :func:`softsbi.scenarios.load_scenario` builds one from a scenario file
    (``softsbi/scenarios/files/*.yaml`` for the built-in ones).

    Attributes:
        name: scenario name, e.g. ``"lift"``.
        times: ``(T,)`` seconds, the frame times at which states are recorded (t[0] = 0).
        gripper: ``(T, 3)`` metres, the first moving handle's commanded path (kept for every
            single-gripper consumer); may be None when ``handles`` are given.
        table_z: height of the table top, metres.
        object: description of the deformable object, e.g.
            ``{"kind": "cloth", "size": 0.28, "corner": [x, y], "direction": [dx, dy]}``; a mesh cloth
            has ``"mesh": {"vertices": (N, 3) m, "faces": (F, 3)}`` at its rest placement.
        options: free-form extras (source recording, notes on derivations).
        handles: every grasp (:class:`Handle`); default one moving handle on the grasped corner
            (cloth) or end (rope) following ``gripper``.
        world: ``{"gravity": [gx, gy, gz] m/s^2, "obstacles": [{"type": "box"|"cylinder", ...}]}``
            (defaults: -9.81 m/s^2 along z, no obstacles besides the table).
        cameras: ``[{"name", "eye", "target", "up", "fovy_deg", "width", "height"}]`` (look-at) or with
            ``"intrinsics": {"fx", "fy", "cx", "cy"}`` px and ``"world_to_cam"`` 3x4 instead of eye/target
            (calibrated); the first renders the scenario's images and is the viewpoint of occlusion
            (:func:`softsbi.scenarios.cameras.scenario_camera`). Empty: the scenario cannot be rendered.
        view: the plane of its 2-D figures: ``"xz"`` (side view across y, the default), ``"yz"`` (side
            view across x) or ``"xy"`` (top view).
        description: one line for humans (the scenario file's ``description``); not in :meth:`to_json` and not
            compared, as it changes no simulation.

    Raises:
        ShapeError: times not ``(T,)`` strictly increasing, a path not ``(T, 3)``, no handle.
    """

    name: str
    times: np.ndarray
    gripper: np.ndarray | None
    table_z: float
    object: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    handles: list[Handle] = field(default_factory=list)
    world: dict[str, Any] = field(default_factory=dict)
    cameras: list[dict[str, Any]] = field(default_factory=list)
    view: str = "xz"
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if self.view not in VIEWS:
            raise ShapeError(f"scenario '{self.name}': view must be one of {list(VIEWS)}, got {self.view!r}")
        self.times = np.asarray(self.times, dtype=float)
        if self.times.ndim != 1:
            raise ShapeError(f"scenario '{self.name}': times must be (T,), got {self.times.shape}")
        T = len(self.times)
        self.handles = [h if isinstance(h, Handle) else Handle.from_json(h) for h in self.handles]
        if self.gripper is None:
            moving = [h for h in self.handles if not h.pinned]
            if not moving:
                raise ShapeError(f"scenario '{self.name}' needs a gripper path or at least one moving handle")
            self.gripper = moving[0].path
        self.gripper = np.asarray(self.gripper, dtype=float)
        if self.gripper.shape != (T, 3):
            raise ShapeError(f"scenario '{self.name}': times must be (T,) and gripper (T, 3); got "
                             f"{self.times.shape} and {self.gripper.shape}")
        if not self.handles:
            grasp = {"end": 0} if self.object.get("kind") == "rope" else {"corner": 0}
            self.handles = [Handle("grip", grasp, self.gripper)]
        for h in self.handles:
            if h.path is not None:
                h.path = np.asarray(h.path, dtype=float)
                if h.path.shape != (T, 3):
                    raise ShapeError(f"scenario '{self.name}': handle '{h.name}' path must be ({T}, 3), "
                                     f"got {h.path.shape}")
        if np.any(np.diff(self.times) <= 0):
            raise ShapeError(f"scenario '{self.name}': frame times must increase strictly")

    @property
    def n_frames(self) -> int:
        return len(self.times)

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0])

    @property
    def gravity(self) -> list[float]:
        """``[gx, gy, gz]`` m/s^2 (default ``[0, 0, -9.81]``)."""
        return [float(v) for v in self.world.get("gravity", (0.0, 0.0, -9.81))]

    def to_json(self) -> dict[str, Any]:
        """JSON-able mapping; ``handles``, ``world``, ``cameras`` and ``view`` only when they are not the defaults
        (one handle on the grasped corner/end following ``gripper``, default world, no camera, ``"xz"``), so a
        single-gripper scenario serialises as it did before handles existed."""
        d = {"name": self.name, "times": self.times.tolist(), "gripper": self.gripper.tolist(),
             "table_z": float(self.table_z), "object": jsonable(self.object), "options": jsonable(self.options)}
        default = {"end": 0} if self.object.get("kind") == "rope" else {"corner": 0}
        h0 = self.handles[0]
        if not (len(self.handles) == 1 and h0.name == "grip" and h0.grasp == default and h0.path is not None
                and np.array_equal(h0.path, self.gripper)):
            d["handles"] = [h.to_json() for h in self.handles]
        if self.world:
            d["world"] = jsonable(self.world)
        if self.cameras:
            d["cameras"] = jsonable(self.cameras)
        if self.view != "xz":
            d["view"] = self.view
        return d

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "Scenario":
        return cls(name=d["name"], times=np.asarray(d["times"]), gripper=np.asarray(d["gripper"]),
                   table_z=float(d["table_z"]), object=dict(d.get("object", {})),
                   options=dict(d.get("options", {})),
                   handles=[Handle.from_json(h) for h in d.get("handles", [])],
                   world=dict(d.get("world", {})), cameras=list(d.get("cameras", [])),
                   view=str(d.get("view", "xz")))


def jsonable(x: Any) -> Any:
    """``x`` with NumPy values, tuples and paths made JSON-serialisable (non-finite floats -> None)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return jsonable(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, PurePath):
        return str(x)
    return x


STATUS_OK = 0
STATUS_DIVERGED = 1
STATUS_IMPLAUSIBLE = 2
STATUS_ERROR = 3
STATUS_PENDING = 255
#: segmentation labels of rendered frames (:attr:`Rollout.segmentation`)
SEG_BACKGROUND = 0
SEG_OBJECT = 1
SEG_ROBOT = 2

STATUS_NAMES = {STATUS_OK: "ok", STATUS_DIVERGED: "diverged", STATUS_IMPLAUSIBLE: "implausible",
                STATUS_ERROR: "error", STATUS_PENDING: "pending"}


#: ``Rollout.info`` key: a visibility threshold (absolute height, m) that a sensor effect sets; observers
#: and metrics see only points above it (with the fit's own threshold, the higher one applies)
INFO_MIN_VISIBLE_Z = "min_visible_z"
#: ``Rollout.info`` key: the radius (m) of the arm's mask that a sensor effect (``arm-mask``) sets; observers and
#: metrics do not see the points within it of the gripper or of the vertical line above it, frame by frame
#: (:func:`softsbi.perception.clouds.arm_hidden`)
INFO_ARM_MASK_RADIUS = "arm_mask_radius"
#: ``Rollout.info`` key: the engine's warnings during the rollout, their texts joined by ``"; "`` (a backend keeps them
#: instead of printing them; the commands tell them once per batch, :class:`softsbi.workflows.reporting.SimulationIssues`)
INFO_ENGINE_WARNINGS = "engine_warnings"


@dataclass
class Rollout:
    """One simulated trajectory of a deformable object.

    Attributes:
        times: ``(T,)`` s.
        gripper: ``(T, 3)`` m, grasp point position at each frame.
        vertices: ``(T, N, 3)`` m, mesh vertex positions.
        faces: ``(F, 3)`` int, triangles indexing ``vertices`` (empty ``(0, 3)`` for a rope).
        status: one of ``STATUS_*`` (0 = ok); anything else means the rollout must not be
            used for training.
        reason: human-readable explanation when ``status != STATUS_OK``.
        rgb: optional ``(T, H, W, 3)`` uint8 frames (filled by :meth:`Simulator.simulate_images`).
        depth: optional ``(T, H, W)`` float32 distance along the camera's optical axis, m.
        segmentation: optional ``(T, H, W)`` uint8 labels ``SEG_*`` (0 table/background,
            1 cloth/rope, 2 robot/gripper).
        info: backend-specific extras (wall time, step count...). Two keys are read by every observer
            and metric: :data:`INFO_MIN_VISIBLE_Z` (absolute height, m; set by a sensor effect such as
            ``table-unseen``): points at or below it are not seen, on top of the fit's own sensor model; and
            :data:`INFO_ARM_MASK_RADIUS` (m; set by ``arm-mask``): points within it of the gripper, or of the
            vertical line above it, are not seen.
    """

    times: np.ndarray
    gripper: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    status: int = STATUS_OK
    reason: str = ""
    rgb: np.ndarray | None = None
    depth: np.ndarray | None = None
    segmentation: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == STATUS_OK

    def validate(self) -> "Rollout":
        """Check shapes; raises :class:`ShapeError` naming the offending array."""
        T = len(self.times)
        if self.gripper.shape != (T, 3):
            raise ShapeError(f"rollout gripper must be ({T}, 3), got {self.gripper.shape}")
        if self.vertices.ndim != 3 or self.vertices.shape[0] != T or self.vertices.shape[2] != 3:
            raise ShapeError(f"rollout vertices must be ({T}, N, 3), got {self.vertices.shape}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ShapeError(f"rollout faces must be (F, 3), got {self.faces.shape}")
        return self


@dataclass
class Observation:
    """What an observer sees: per-frame point sets plus the gripper.

    Attributes:
        points: ``(T, K, 3)`` m (3-D clouds/keypoints) or ``(T, K, 2)`` px (image keypoints);
            the K points of a frame are an unordered set.
        gripper: ``(T, 3)`` m.
        times: ``(T,)`` s.
        source: where it came from (path or ``"simulated:<backend>"``).
        image_size: ``(width, height)`` px of the images 2-D keypoints were found in (None for 3-D).
    """

    points: np.ndarray
    gripper: np.ndarray
    times: np.ndarray
    source: str = ""
    image_size: tuple[int, int] | None = None

    def state(self) -> np.ndarray:
        """The per-frame state ``s_t = [gripper, k_1..k_K]`` as ``(T, 1 + K, 3)``.

        3-D points are kept in metres. 2-D keypoints ``(u, v)`` px become ``(u / W, v / H, 0)``
        (image-normalised, so the state does not depend on the resolution); the gripper row stays
        in metres.

        Raises:
            ShapeError: points neither ``(T, K, 3)`` nor ``(T, K, 2)``, or 2-D keypoints without
                ``image_size``.
        """
        pts = np.asarray(self.points, float)
        if pts.ndim != 3 or pts.shape[-1] not in (2, 3) or len(pts) != len(self.gripper):
            raise ShapeError(f"observation points must be (T, K, 3) or (T, K, 2) with T = {len(self.gripper)}, "
                             f"got {pts.shape}")
        if pts.shape[-1] == 2:
            if self.image_size is None:
                raise ShapeError("2-D keypoints need Observation.image_size = (width, height) to build the state")
            w, h = self.image_size
            pts = np.concatenate([pts / np.array([w, h], float), np.zeros(pts.shape[:2] + (1,))], axis=-1)
        return np.concatenate([np.asarray(self.gripper, float)[:, None, :], pts], axis=1)


@dataclass
class Recording:
    """What a fit is fitted to: a real recording or a simulated one, in the scenario's frame (metres).

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
        min_height, frames: the recording's sensor model (see below).
    """

    scenario: Scenario
    x: np.ndarray | None
    dense: np.ndarray | None
    source: str
    truth: dict[str, float] | None = None
    images: np.ndarray | None = None
    #: the sensor's defaults for a fit that does not set them (``FitConfig.min_height`` and
    #: ``FitConfig.frames`` None): points closer than ``min_height`` m to the table are not seen
    #: (None: all are), and the frames that inform the posterior (``"auto"``: those where the
    #: gripper is at least 10 cm above the table; ``"all"``; or indices)
    min_height: float | None = None
    frames: str | list[int] | None = "all"
