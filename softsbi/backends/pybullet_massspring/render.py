"""``pybullet-massspring`` rendering: :class:`PbFrameRenderer`, the frame renderer of
:meth:`~softsbi.core.interfaces.Simulator.simulate_images` for PyBullet.

PyBullet's CPU TinyRenderer in the rollout's own DIRECT client, one ``getCameraImage`` per
recorded frame giving colour, depth and the segmentation mask at once. The view matrix is the
camera's ``[R | t]`` with OpenCV axes flipped to OpenGL's (y up, looking along -z); the projection
matrix is built from the exact intrinsics (``fx, fy, cx, cy``, near/far :data:`NEAR`/:data:`FAR`),
with TinyRenderer's half-pixel offsets compensated (measured: without it, rendered spheres sit
+0.5 px right and 0.5 px up of ``Camera.project``). Depth is the linearised z-buffer
``near far / (far - (far - near) z)`` (m along the optical axis). The visual-only robot
(:func:`~softsbi.backends.common.visual_robot`) is two collision-free, mass-0 multibodies created
after the cloth and moved to each frame's grasp point before rendering (the arm is a square bar
of the capsule's size: TinyRenderer shades capsule sides wrongly): they do not change the physics
(vertices bit-identical to :meth:`PybulletMassSpring.simulate`). Segmentation mask ids map to
labels: soft body -> 1, robot bodies -> 2, table/spool/nothing -> 0. No OpenGL is needed.
"""
from __future__ import annotations

import time
from typing import Any, Mapping, NamedTuple

import numpy as np

from softsbi.backends.common import PROP_COLOUR, FrameRenderer, rgba, visual_robot
from softsbi.backends.pybullet_massspring.model import import_pybullet
from softsbi.core.types import SEG_BACKGROUND, SEG_OBJECT, SEG_ROBOT, Scenario

#: clipping planes of the rendering projection, m
NEAR, FAR = 0.01, 20.0


def gl_matrices(camera: Any, near: float = NEAR, far: float = FAR) -> tuple[list[float], list[float]]:
    """PyBullet ``(viewMatrix, projectionMatrix)`` (16 floats each, column-major) of an OpenCV
    :class:`~softsbi.core.camera.Camera`, for ``getCameraImage`` with the TinyRenderer.

    The projection maps ``u = fx x/z + cx``, ``v = fy y/z + cy`` exactly, including TinyRenderer's
    half-pixel conventions (its pixel (i, j) is sampled at (i - 0.5, j + 0.5) of OpenCV's grid).
    """
    W, H = camera.width, camera.height
    V = np.eye(4)
    V[:3, :4] = np.diag([1.0, -1.0, -1.0]) @ np.asarray(camera.world_to_cam, dtype=float)
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * camera.fx / W
    P[0, 2] = 1.0 - 2.0 * camera.cx / W
    P[1, 1] = 2.0 * camera.fy / H
    P[1, 2] = 2.0 * (camera.cy + 1.0) / H - 1.0
    P[2, 2] = -(far + near) / (far - near)
    P[2, 3] = -2.0 * far * near / (far - near)
    P[3, 2] = -1.0
    return V.T.ravel().tolist(), P.T.ravel().tolist()


class PbState(NamedTuple):
    """What the stepping loop hands the renderer per frame: the physics client id ``cid``, the body
    ids ``bodies`` (``{"table", "soft", "spool"?}``) and the grasp target ``grip (3,)`` m."""

    cid: int
    bodies: Mapping[str, int]
    grip: np.ndarray


class PbFrameRenderer(FrameRenderer):
    """Renders each recorded frame of a PyBullet rollout (``PybulletMassSpring._rollout``'s
    ``frames``) with the TinyRenderer; on frame 0 it colours the bodies and adds the visual robot.
    Outputs: see :class:`~softsbi.backends.common.FrameRenderer`; nothing to close.
    """

    def __init__(self, scenario: Scenario, camera: Any, style: Any):
        super().__init__(scenario, camera, style)
        self.view, self.proj = gl_matrices(camera)
        self.robot: list[tuple[int, str]] = []
        self.lut: dict[int, int] = {}

    def _setup(self, cid: int, bodies: Mapping[str, int], grip: np.ndarray) -> None:
        p = import_pybullet()
        st = self.style
        p.changeVisualShape(bodies["table"], -1, rgbaColor=rgba(st.table), physicsClientId=cid)
        if "spool" in bodies:
            p.changeVisualShape(bodies["spool"], -1, rgbaColor=rgba(PROP_COLOUR), physicsClientId=cid)
        p.changeVisualShape(bodies["soft"], -1, rgbaColor=rgba(st.cloth), flags=p.VISUAL_SHAPE_DOUBLE_SIDED,
                            physicsClientId=cid)
        self.lut = {bodies["soft"]: SEG_OBJECT}
        if st.show_robot:
            for part in visual_robot(grip, self.base):
                colour = rgba(st.gripper if part["part"] == "gripper" else st.robot)
                if part["shape"] == "box":
                    vs = p.createVisualShape(p.GEOM_BOX, halfExtents=[float(v) for v in part["size"]],
                                             rgbaColor=colour, physicsClientId=cid)
                else:
                    # the arm as a square bar of the capsule's width and length (no caps): TinyRenderer
                    # lights the sides of capsules/cylinders as if their normals pointed inwards
                    # (a tilted white capsule renders at ambient grey), flat faces are lit correctly
                    r, hl = float(part["size"][0]), float(part["size"][1])
                    vs = p.createVisualShape(p.GEOM_BOX, halfExtents=[r, r, hl], rgbaColor=colour,
                                             physicsClientId=cid)
                # no collision shape, mass 0: invisible to the physics
                body = p.createMultiBody(0, -1, vs, physicsClientId=cid)
                self.robot.append((body, part["part"]))
                self.lut[body] = SEG_ROBOT

    def __call__(self, k: int, state: PbState) -> None:
        """Render frame ``k`` (colour, depth, segmentation) from ``state = (cid, bodies, grip)``."""
        cid, bodies, grip = state
        from scipy.spatial.transform import Rotation  # heavy (~1 s): only rendering needs it
        p = import_pybullet()
        t0 = time.perf_counter()
        if k == 0:
            self._setup(cid, bodies, grip)
            self.setup_seconds = time.perf_counter() - t0
        if self.robot:
            parts = {q["part"]: q for q in visual_robot(grip, self.base)}
            for body, name in self.robot:
                q = parts[name]
                p.resetBasePositionAndOrientation(body, [float(v) for v in q["pos"]],
                                                  Rotation.from_matrix(q["rot"]).as_quat().tolist(),
                                                  physicsClientId=cid)
        W, H = self.camera.width, self.camera.height
        _, _, rgba, zbuf, ids = p.getCameraImage(W, H, self.view, self.proj, renderer=p.ER_TINY_RENDERER,
                                                 shadow=0, lightDirection=[0.3, -0.2, 1.0],
                                                 lightAmbientCoeff=0.45, lightDiffuseCoeff=0.55,
                                                 lightSpecularCoeff=0.0, physicsClientId=cid)
        self.rgb[k] = np.asarray(rgba, dtype=np.uint8).reshape(H, W, 4)[..., :3]
        z = np.asarray(zbuf, dtype=np.float64).reshape(H, W)
        self.depth[k] = (NEAR * FAR / (FAR - (FAR - NEAR) * z)).astype(np.float32)
        ids = np.asarray(ids, dtype=np.int64).reshape(H, W)
        lab = np.full((H, W), SEG_BACKGROUND, np.uint8)
        for body, label in self.lut.items():
            lab[ids == body] = label
        self.segmentation[k] = lab
        self.seconds += time.perf_counter() - t0

