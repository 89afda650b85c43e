"""Rendering helpers: render a rollout by backend name, robot masks from depth, contact sheets, GIFs.

The renderers themselves live in the backends (:meth:`MujocoFlex.simulate_images`,
:meth:`PybulletMassSpring.simulate_images`); this module is the convenience layer around them and the
image utilities that need no simulator. Cameras and colours: :mod:`softsbi.core.camera`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.core.camera import Camera, RenderStyle
from softsbi.scenarios.cameras import scenario_camera
from softsbi.core.errors import DataError, DependencyMissing, ShapeError
from softsbi.core.types import Rollout, Scenario
from softsbi.plugins import registry
from softsbi.scenarios.builtin import make_scenario


def backproject_depth(depth: np.ndarray, camera: Camera) -> np.ndarray:
    """World points ``(..., H, W, 3)`` m of a depth image ``(..., H, W)`` (m along the optical axis).

    Pixel ``(u, v)`` at depth ``z`` is the camera point ``((u - cx) z / fx, (v - cy) z / fy, z)``,
    mapped to the world with ``R^T (p_c - t)``.

    Raises:
        ShapeError: the last two axes are not ``(camera.height, camera.width)``.
    """
    depth = np.asarray(depth, dtype=float)
    if depth.ndim < 2 or depth.shape[-2:] != (camera.height, camera.width):
        raise ShapeError(f"depth must be (..., {camera.height}, {camera.width}) for this camera, got {depth.shape}")
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(float)
    pc = np.stack([(u - camera.cx) / camera.fx * depth, (v - camera.cy) / camera.fy * depth, depth], axis=-1)
    return (pc - camera.t) @ camera.R


def robot_mask_from_depth(depth: np.ndarray, camera: Camera, table_z: float, min_height: float = 0.03) -> np.ndarray:
    """Pixels whose visible surface lies more than ``min_height`` above the table: the robot, when
    the object stays near the table (wiping).

    Args:
        depth: ``(H, W)`` or ``(T, H, W)`` float, m along the optical axis (``Rollout.depth``).
        camera: the camera that took it (``H, W = camera.height, camera.width``).
        table_z: table height, m (``Scenario.table_z``).
        min_height: threshold above the table, m (default 3 cm: above a lying or slightly lifted
            cloth, below the robot's gripper top).

    Returns:
        bool array of ``depth``'s shape; non-finite or non-positive depths are False.

    Raises:
        ShapeError: depth not ``(..., H, W)`` of this camera.
    """
    d = np.asarray(depth, dtype=float)
    z = backproject_depth(d, camera)[..., 2]
    with np.errstate(invalid="ignore"):
        return np.isfinite(d) & (d > 0) & (z > float(table_z) + float(min_height))


def save_frames_png(frames: np.ndarray, path: str | Path, ncols: int = 6, labels: Sequence[str] | None = None,
                    title: str | None = None, scale: float = 1.0) -> Path:
    """Write a contact sheet of frames (matplotlib, Agg) with a label above each frame.

    Args:
        frames: ``(T, H, W, 3)`` uint8 RGB, or ``(T, H, W)`` masks (bool) / grey images (any numeric).
        path: output ``.png`` (parent folders are created).
        ncols: frames per row.
        labels: ``T`` strings (default ``"frame k"``).
        title: optional figure title.
        scale: figure size factor (1.0: a 128 px frame is drawn about 1.6 inches wide).

    Returns:
        The written path.

    Raises:
        ShapeError: frames not ``(T, H, W)`` or ``(T, H, W, 3)`` (a ``(T, H, 3)`` stack is taken for
            one RGB image and refused), or ``len(labels) != T``.
    """
    import matplotlib  # heavy (~1.7 s with pyplot): only the contact sheet draws
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only the contact sheet draws

    f = np.asarray(frames)
    if not (f.ndim == 3 or (f.ndim == 4 and f.shape[-1] == 3)) or len(f) == 0:
        raise ShapeError(f"frames must be (T, H, W, 3) RGB or (T, H, W) masks with T >= 1, got {f.shape}")
    if f.ndim == 3 and f.shape[-1] == 3:
        raise ShapeError(f"frames of shape {f.shape} look like one RGB image; pass frames[None] for a single image")
    T = len(f)
    labels = [f"frame {k}" for k in range(T)] if labels is None else list(labels)
    if len(labels) != T:
        raise ShapeError(f"{len(labels)} labels for {T} frames")
    ncols = max(1, min(int(ncols), T))
    nrows = -(-T // ncols)
    h, w = f.shape[1:3]
    cw = 1.6 * scale * max(w, 64) / 128
    ch = cw * h / w + 0.3 * scale
    fig, axes = plt.subplots(nrows, ncols, figsize=(cw * ncols, ch * nrows + (0.4 if title else 0)), squeeze=False)
    for k, ax in enumerate(axes.ravel()):
        ax.axis("off")
        if k >= T:
            continue
        img = f[k]
        if img.ndim == 2:
            ax.imshow(img.astype(float), cmap="gray", interpolation="nearest",
                      vmin=0.0 if img.dtype == bool else None, vmax=1.0 if img.dtype == bool else None)
        else:
            ax.imshow(img.astype(np.uint8), interpolation="nearest")
        ax.set_title(labels[k], fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def save_gif(frames: np.ndarray, path: str | Path, fps: float = 10.0, loop: int = 0) -> Path:
    """Write ``(T, H, W, 3)`` uint8 RGB frames as an animated GIF (Pillow, installed with matplotlib).

    Raises:
        ShapeError: frames not ``(T, H, W, 3)`` uint8.
        DependencyMissing: Pillow is not installed.
    """
    f = np.asarray(frames)
    if f.ndim != 4 or f.shape[-1] != 3 or f.dtype != np.uint8 or len(f) == 0:
        raise ShapeError(f"frames must be (T, H, W, 3) uint8 with T >= 1, got {f.shape} {f.dtype}")
    try:
        from PIL import Image  # optional: Pillow
    except ImportError as exc:  # pragma: no cover - Pillow comes with matplotlib
        raise DependencyMissing("writing GIFs needs Pillow: pip install pillow") from exc
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    imgs = [Image.fromarray(x) for x in f]
    imgs[0].save(path, save_all=True, append_images=imgs[1:], duration=int(round(1000.0 / fps)), loop=loop)
    return path


def render_rollout(backend_name: str, scenario: Scenario | str, theta: Mapping[str, float] | None = None,
                   camera: Camera | None = None, size: int = 128, style: RenderStyle | None = None,
                   effects: Sequence[str] = (), seed: int = 0, **backend_options: Any) -> Rollout:
    """Simulate and render one rollout with a registered backend.

    Args:
        backend_name: simulator plugin name (``"mujoco-flex"``, ``"pybullet-massspring"``).
        scenario: a :class:`Scenario` or a scenario name (built with
            :func:`softsbi.scenarios.builtin.make_scenario`).
        theta: parameters (physical units); None -> the midpoint of the backend's prior box.
        camera: None -> the scenario's camera (:func:`~softsbi.scenarios.cameras.scenario_camera`).
        size: image side, px, of the scenario's camera (None: its declared size).
        style: colours / ``show_robot`` (default :class:`RenderStyle`).
        effects, seed: as in :meth:`Simulator.simulate`.
        backend_options: passed to the backend's constructor (``grid=7``...).

    Returns:
        The rollout with ``rgb (T, H, W, 3)``, ``depth (T, H, W)`` m and ``segmentation (T, H, W)``.

    Raises:
        PluginNotFound: unknown backend. DataError: no camera given and none declared by the scenario.
        NotImplementedError: the backend cannot render.
    """
    if isinstance(scenario, str):
        scenario = make_scenario(scenario)
    if not isinstance(scenario, Scenario):
        raise DataError(f"scenario must be a Scenario or a scenario name, got {type(scenario).__name__}")
    cls = registry().simulator(backend_name)
    sim = cls(**backend_options) if isinstance(cls, type) else cls
    if theta is None:
        space = sim.full_space(scenario, effects) if hasattr(sim, "full_space") else sim.param_space(scenario)
        theta = space.midpoint()
    cam = scenario_camera(scenario, size) if camera is None else camera
    try:
        return sim.simulate_images(scenario, theta, cam, effects=effects, seed=seed, style=style)
    finally:
        close = getattr(sim, "close", None)
        if callable(close):
            close()
