"""Rendered training sets for the keypoint extractors and rendered measurements.

Extractors that run on simulated frames are trained on frames rendered at parameters drawn from
the prior, so they see every cloth the fit will simulate. Labels come for free from the simulator:
the cloth corners projected through the camera (supervised ``heatmap``) and the robot mask from
the depth image (unsupervised ``transporter``, whose reconstruction loss ignores the robot).
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np

from softsbi.core.camera import Camera, RenderStyle
from softsbi.scenarios.cameras import scenario_camera
from softsbi.core.errors import SimulationFailed, SoftsbiError
from softsbi.core.types import SEG_OBJECT, SEG_ROBOT, Scenario
from softsbi.core.seeds import SYNTH_STREAM
from softsbi.plugins import registry
from softsbi.scenarios.builtin import make_scenario


def corner_keypoints(rollout: Any, camera: Camera) -> np.ndarray:
    """Pixel positions ``(T, 4, 2)`` (u, v) of the cloth's four corners in every rendered frame.

    Raises:
        SoftsbiError: the rollout does not name its corners (``info["corners"]``, filled by the
            built-in backends for cloth scenarios).
    """
    corners = rollout.info.get("corners")
    if not corners or len(corners) != 4:
        raise SoftsbiError("the rollout has no info['corners'] (4 corner vertex indices); corner labels need a "
                           "cloth scenario on a backend that reports its corners (mujoco-flex, pybullet-massspring)")
    uv, _ = camera.project(np.asarray(rollout.vertices)[:, list(corners)])
    return uv


def render_training_set(backend: str = "mujoco-flex", scenario: Scenario | str = "wipe", n_rollouts: int = 40,
                        size: int = 128, camera: Camera | None = None, style: RenderStyle | None = None,
                        backend_options: Mapping[str, Any] | None = None, fixed: Mapping[str, float] | None = None,
                        frames: Sequence[int] | None = None, seed: int = 0,
                        progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Render ``n_rollouts`` rollouts at parameters drawn uniformly from the backend's prior.

    Args:
        backend: simulator plugin that implements ``simulate_images``.
        scenario: a :class:`Scenario` or a scenario name for :func:`~softsbi.scenarios.builtin.make_scenario`.
        n_rollouts: rollouts (failed ones are skipped and replaced, at most ``2 n_rollouts`` tries).
        size: square image size when ``camera`` is None (the scenario's camera).
        fixed: parameters held at a value instead of drawn.
        frames: frame indices kept per rollout (None = all).
        progress: ``progress(done, total)`` after each rollout.

    Returns:
        ``images (N, H, W, 3)`` uint8, ``corners (N, 4, 2)`` px (u, v), ``robot_masks (N, H, W)``
        bool, ``cloth_masks (N, H, W)`` bool, ``depth (N, H, W)`` float32 m, ``sequence_ids (N,)``
        int (rollout index of each frame), ``theta (R, D)`` physical, ``names`` (D,).

    Raises:
        SimulationFailed: more than half the rollouts failed. PluginNotFound: unknown backend.
    """
    sc = make_scenario(scenario) if isinstance(scenario, str) else scenario
    cam = camera or scenario_camera(sc, size)
    sim = registry().simulator(backend)(**dict(backend_options or {}))
    space = sim.param_space(sc)
    rng = np.random.default_rng([seed, SYNTH_STREAM])
    keep = slice(None) if frames is None else list(frames)
    out: dict[str, list] = {k: [] for k in ("images", "corners", "robot_masks", "cloth_masks", "depth", "sequence_ids")}
    thetas, tries = [], 0
    while len(thetas) < n_rollouts:
        tries += 1
        if tries > 2 * n_rollouts:
            raise SimulationFailed(f"{tries - 1 - len(thetas)} of {tries - 1} rollouts failed while rendering a "
                                   f"training set; narrow the prior or check the backend")
        theta = space.as_dict(space.from_unit(rng.random(space.dim)))
        theta.update(dict(fixed or {}))
        ro = sim.simulate_images(sc, theta, camera=cam, style=style, seed=int(rng.integers(2**31)))
        if not ro.ok or ro.rgb is None:
            continue
        i = len(thetas)
        thetas.append([theta[n] for n in space.names])
        seg = np.asarray(ro.segmentation)[keep]
        out["images"].append(np.asarray(ro.rgb)[keep])
        out["corners"].append(corner_keypoints(ro, cam)[keep])
        out["robot_masks"].append(seg == SEG_ROBOT)
        out["cloth_masks"].append(seg == SEG_OBJECT)
        out["depth"].append(np.asarray(ro.depth, np.float32)[keep])
        out["sequence_ids"].append(np.full(len(seg), i))
        if progress:
            progress(i + 1, n_rollouts)
    res = {k: np.concatenate(v) for k, v in out.items()}
    res["theta"] = np.asarray(thetas, float)
    res["names"] = np.asarray(space.names)
    return res


def visible_corner_labels(corners: np.ndarray, width: int, height: int) -> np.ndarray:
    """Clip corner labels ``(N, 4, 2)`` px into the image (a corner outside the frame is labelled at
    the nearest border pixel, like an annotator would click the edge)."""
    c = np.array(corners, float)
    c[..., 0] = np.clip(c[..., 0], 0, width - 1)
    c[..., 1] = np.clip(c[..., 1], 0, height - 1)
    return c
