"""Pinhole cameras and the look of a rendered scene (shared by every renderer and extractor).

Conventions (OpenCV): camera axes x right, y down, z forward (optical axis); pixel ``(u, v)`` =
``(column, row)`` with ``(0, 0)`` the centre of the top-left pixel. A world point ``p`` (m, row
vector) maps to camera coordinates ``p_c = R p + t`` with ``world_to_cam = [R | t]`` (3x4), and to
pixels ``u = fx x_c / z_c + cx``, ``v = fy y_c / z_c + cy``.

The DiffCloud calibration files (``../shared/data/diffcloud_lift/calib_*``: ``intrinsics.npy`` =
``(fx, fy, cx, cy)`` for 640x480, ``trc.npy`` = robot->camera 3x4) are cameras of this kind:
:meth:`Camera.from_calibration` reads them.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.core.arrays import read_npy
from softsbi.core.errors import DataError, ShapeError


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes:
        width, height: image size, px.
        fx, fy: focal lengths, px. cx, cy: principal point, px.
        world_to_cam: ``(3, 4)`` ``[R | t]``, world (m) -> camera (m), OpenCV axes.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_to_cam: tuple = field(default=((1.0, 0, 0, 0), (0, 1.0, 0, 0), (0, 0, 1.0, 0)))

    def __post_init__(self) -> None:
        m = np.asarray(self.world_to_cam, dtype=float)
        if m.shape != (3, 4):
            raise ShapeError(f"world_to_cam must be 3x4 [R | t], got shape {m.shape}")
        if not np.allclose(m[:, :3] @ m[:, :3].T, np.eye(3), atol=1e-4):
            raise DataError("world_to_cam's left 3x3 block is not a rotation (R R^T != I)")
        if np.linalg.det(m[:, :3]) < 0:
            raise DataError("world_to_cam's left 3x3 block is a reflection (det < 0), which would render mirror "
                            "images; flip the sign of one camera axis")
        if self.width < 8 or self.height < 8:
            raise DataError(f"camera image size must be at least 8x8 px, got {self.width}x{self.height}")
        if self.fx <= 0 or self.fy <= 0:
            raise DataError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        object.__setattr__(self, "world_to_cam", tuple(tuple(float(v) for v in r) for r in m))

    # -- construction ------------------------------------------------------------------
    @classmethod
    def look_at(cls, eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0, 0, 1),
                fovy_deg: float = 45.0, width: int = 128, height: int = 128) -> "Camera":
        """A camera at ``eye`` (m) looking at ``target`` (m), square pixels, vertical field of view
        ``fovy_deg``. ``up`` fixes the roll: it points towards the top of the image.

        Raises:
            DataError: ``eye == target`` or ``up`` parallel to the viewing direction.
        """
        eye, target, up = (np.asarray(a, dtype=float) for a in (eye, target, up))
        z = target - eye
        if np.linalg.norm(z) < 1e-9:
            raise DataError("look_at: eye and target coincide")
        z /= np.linalg.norm(z)
        x = np.cross(z, up)  # image right; then image down = z x right = -up (projected)
        if np.linalg.norm(x) < 1e-9:
            raise DataError("look_at: 'up' is parallel to the viewing direction; pass another up vector")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        f = 0.5 * height / np.tan(np.radians(fovy_deg) / 2)
        return cls(width, height, f, f, (width - 1) / 2, (height - 1) / 2,
                   np.hstack([R, (-R @ eye)[:, None]]))

    @classmethod
    def from_calibration(cls, folder: str | Path, width: int = 640, height: int = 480) -> "Camera":
        """A camera from a DiffCloud-style calibration folder (``intrinsics.npy`` ``(fx, fy, cx, cy)``,
        ``trc.npy`` world/robot -> camera 3x4).

        Raises:
            DataError: missing files or wrong shapes.
        """
        folder = Path(folder)
        fix = f"calibration folder '{folder}' needs intrinsics.npy (4,) and trc.npy (3, 4)"
        k = read_npy(folder / "intrinsics.npy", "camera intrinsics", fix)
        trc = read_npy(folder / "trc.npy", "camera pose", fix)
        if k.shape != (4,) or trc.shape != (3, 4):
            raise DataError(f"'{folder}': intrinsics must be (4,) and trc (3, 4), got {k.shape} and {trc.shape}")
        return cls(width, height, *map(float, k), trc)

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera with the image rescaled to ``width x height`` px (intrinsics scaled)."""
        sx, sy = width / self.width, height / self.height
        return Camera(width, height, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
                      (self.cy + 0.5) * sy - 0.5, self.world_to_cam)

    # -- geometry ----------------------------------------------------------------------
    @property
    def R(self) -> np.ndarray:
        """``(3, 3)`` rotation world -> camera (rows: camera x, y, z axes in world coordinates)."""
        return np.asarray(self.world_to_cam)[:, :3]

    @property
    def t(self) -> np.ndarray:
        """``(3,)`` translation world -> camera, m."""
        return np.asarray(self.world_to_cam)[:, 3]

    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates, m."""
        return -self.R.T @ self.t

    @property
    def fovy_deg(self) -> float:
        """Vertical field of view, degrees."""
        return float(np.degrees(2 * np.arctan(0.5 * self.height / self.fy)))

    @property
    def K(self) -> np.ndarray:
        """``(3, 3)`` intrinsic matrix."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` m -> camera coordinates ``(..., 3)`` m."""
        return np.asarray(points, dtype=float) @ self.R.T + self.t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points ``(..., 3)`` m -> pixels ``(..., 2)`` ``(u, v)`` and depth ``(...,)`` m
        (distance along the optical axis; points behind the camera get depth <= 0)."""
        pc = self.to_camera(points)
        z = pc[..., 2]
        zs = np.where(np.abs(z) < 1e-9, 1e-9, z)
        uv = np.stack([self.fx * pc[..., 0] / zs + self.cx, self.fy * pc[..., 1] / zs + self.cy], axis=-1)
        return uv, z

    def to_json(self) -> dict[str, Any]:
        """JSON-able dict (the run store and observer options keep cameras this way)."""
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy, "cx": self.cx,
                "cy": self.cy, "world_to_cam": [list(r) for r in self.world_to_cam]}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "Camera":
        """Inverse of :meth:`to_json`."""
        return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]),
                   float(d["cy"]), tuple(tuple(r) for r in d["world_to_cam"]))


@dataclass(frozen=True)
class RenderStyle:
    """Colours (RGB, 0-255) of a rendered scene. The defaults are close to the paper's real wiping
    images (``../shared/data/wiping_keypoints``): a green cloth on a salmon-red table, white arm and
    black gripper."""

    cloth: tuple[int, int, int] = (101, 144, 122)  # median colour of the real cloth (frames 0-280)
    table: tuple[int, int, int] = (175, 103, 112)  # median colour of the real table
    robot: tuple[int, int, int] = (225, 225, 225)
    gripper: tuple[int, int, int] = (30, 30, 34)
    show_robot: bool = True

    def to_json(self) -> dict[str, Any]:
        return {"cloth": list(self.cloth), "table": list(self.table), "robot": list(self.robot),
                "gripper": list(self.gripper), "show_robot": self.show_robot}

    @classmethod
    def from_json(cls, d: Mapping[str, Any] | None) -> "RenderStyle":
        if not d:
            return cls()
        return cls(tuple(d.get("cloth", cls.cloth)), tuple(d.get("table", cls.table)),
                   tuple(d.get("robot", cls.robot)), tuple(d.get("gripper", cls.gripper)),
                   bool(d.get("show_robot", True)))
