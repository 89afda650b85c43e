"""``mujoco-flex`` rendering: :class:`MjFrameRenderer`, the frame renderer of
:meth:`~softsbi.core.interfaces.Simulator.simulate_images` for MuJoCo.

The same model as the simulation plus a fixed camera with the exact pinhole intrinsics
(``focalpixel``/``principalpixel``/``sensorsize``; OpenCV axes converted to MuJoCo's camera
frame, which looks along -z with y up), one directional light from above and the headlight off;
shadows and reflections are switched off after every ``update_scene`` (5 ms per 320 px frame
instead of ~50 ms). Cameras, lights and colours do not enter the physics: the vertices are
bit-identical to :meth:`MujocoFlex.simulate`. The robot is *visual only*: geoms added to the
rendered scene (:func:`~softsbi.backends.common.visual_robot`), never to the model.
Segmentation comes from MuJoCo's segmentation rendering (flex -> ``SEG_OBJECT``, the added robot
geoms -> ``SEG_ROBOT``, everything else -> ``SEG_BACKGROUND``), depth from the linearised depth
buffer (metres along the optical axis). Off-screen OpenGL is chosen only when the first frame is
rendered (:mod:`.gl`): ``MUJOCO_GL`` if set, else OSMesa if its library loads, else EGL.
"""
from __future__ import annotations

import time
from typing import Any, NamedTuple, Sequence

import numpy as np

from softsbi.backends.common import PROP_COLOUR, FrameRenderer, rgba, visual_robot
from softsbi.backends.mujoco_flex.gl import RENDER_FIX, choose_backend, gl_context_class, import_mujoco
from softsbi.core.errors import RenderingUnavailable
from softsbi.core.types import SEG_BACKGROUND, SEG_OBJECT, SEG_ROBOT, Scenario


def _rgba(c: Sequence[int]) -> np.ndarray:
    """RGB 0-255 -> float32 ``(4,)`` RGBA in 0-1 (MuJoCo's ``geom_rgba``)."""
    return np.array(rgba(c), dtype=np.float32)


class MjState(NamedTuple):
    """What the stepping loop hands the renderer per frame: the compiled ``model`` (``MjModel``)
    and its ``data`` (``MjData``), the grasp target in ``data.mocap_pos[0]``."""

    model: Any
    data: Any


#: objid given to the added robot geoms in the rendered scene (segmentation decoding)
_ROBOT_OBJID = -1000


class MjFrameRenderer(FrameRenderer):
    """Renders each recorded frame of a MuJoCo rollout (``MujocoFlex._rollout``'s ``frames``).

    Low-level pipeline (``mjv_updateScene`` -> ``mjr_render`` -> ``mjr_readPixels``) rather than
    ``mujoco.Renderer``, so that one pass reads colour *and* depth (the Renderer needs a pass for
    each) and a second pass the segmentation: 2 passes per frame instead of 3. The GL context is
    opened on the first frame (``RenderingUnavailable`` when no back-end works) and released by
    :meth:`close`. Outputs: see :class:`~softsbi.backends.common.FrameRenderer`.
    """

    CAMERA = "softsbi_cam"

    def __init__(self, scenario: Scenario, camera: Any, style: Any):
        super().__init__(scenario, camera, style)
        H, W = camera.height, camera.width
        self._buf_rgb = np.zeros((H, W, 3), np.uint8)
        self._buf_depth = np.zeros((H, W), np.float32)
        self.gl = self.ctx = None

    def edit(self, spec: dict[str, Any]) -> None:
        """Add the camera (exact intrinsics), a light from above and off-screen buffer settings to
        the model dict of :func:`~softsbi.backends.mujoco_flex.model.build_spec` (``spec["render"]``)."""
        cam = self.camera
        W, H = cam.width, cam.height
        R = cam.R
        # OpenCV camera axes (x right, y down, z forward) -> MuJoCo's (x right, y up, looking along -z)
        xa, ya = R[0], -R[1]
        pitch = 1e-4  # m per pixel of a virtual sensor: only the focal/sensor ratio matters
        # MuJoCo's principal offset moves the image content the other way than OpenCV's (cx, cy)
        # (checked by projecting spheres: agreement within 0.3 px, tests/test_render.py)
        camera = {"name": self.CAMERA, "pos": cam.position.tolist(), "xyaxes": list(xa) + list(ya),
                  "resolution": [W, H], "sensorsize": [W * pitch, H * pitch],
                  "focalpixel": [cam.fx, cam.fy], "principalpixel": [(W - 1) / 2 - cam.cx, (H - 1) / 2 - cam.cy]}
        light = {"name": "softsbi_sun", "pos": [0.0, 0.0, 3.0], "dir": [0.0, 0.0, -1.0], "directional": "true",
                 "castshadow": "false", "ambient": [0.45] * 3, "diffuse": [0.55] * 3, "specular": [0.0] * 3}
        spec["render"] = {
            # no shadow map, no multisampling (software MSAA is slow and would blend segmentation ids)
            "visual": {"global": {"offwidth": max(640, W), "offheight": max(480, H)},
                       "headlight": {"active": 0, "ambient": [0.0] * 3, "diffuse": [0.0] * 3, "specular": [0.0] * 3},
                       "quality": {"shadowsize": 0, "offsamples": 0}},
            "bodies": [("camera", camera), ("light", light)],
        }

    def _setup(self, m: Any) -> None:
        mujoco = import_mujoco()
        table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
        for g in range(m.ngeom):
            m.geom_rgba[g] = _rgba(self.style.table if g == table else PROP_COLOUR)
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
                # size[2] of a plane is only its rendering grid spacing (1 cm: 160 000 quads, ~6 ms a
                # frame in software GL); one quad suffices under a directional light. No physics effect.
                m.geom_size[g, 2] = max(float(m.geom_size[g, 0]), float(m.geom_size[g, 1]), 1.0)
        m.flex_rgba[:] = _rgba(self.style.cloth)
        cls = gl_context_class()  # RenderingUnavailable names the fix
        try:
            self.gl = cls(max(640, self.camera.width), max(480, self.camera.height))
            self.gl.make_current()
            self.ctx = mujoco.MjrContext(m, mujoco.mjtFontScale.mjFONTSCALE_100)
        except Exception as exc:
            self.close()
            raise RenderingUnavailable(f"MuJoCo could not open an off-screen OpenGL context with back-end "
                                       f"{choose_backend()!r} ({type(exc).__name__}: {exc}); {RENDER_FIX}") from exc
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.ctx)
        self.ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR  # reversed z (as mujoco.Renderer)
        self.scene = mujoco.MjvScene(m, maxgeom=m.ngeom + m.nflex + 16)
        self.opt = mujoco.MjvOption()
        self.cam = mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self.cam.fixedcamid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, self.CAMERA)
        self.rect = mujoco.MjrRect(0, 0, self.camera.width, self.camera.height)
        # reversed-z depth buffer -> metres along the optical axis (mujoco.Renderer's formula)
        near = np.float32(m.vis.map.znear * m.stat.extent)
        far = np.float32(m.vis.map.zfar * m.stat.extent)
        self._c = float(np.float32(-0.5) * (-(far + near) / (far - near)) - np.float32(0.5))
        self._d = float(np.float32(-0.5) * (-(np.float32(2) * far * near) / (far - near)))

    def _add_robot(self, scene: Any, grip: np.ndarray) -> None:
        mujoco = import_mujoco()
        for part in visual_robot(grip, self.base):
            if scene.ngeom >= scene.maxgeom:
                break
            g = scene.geoms[scene.ngeom]
            colour = self.style.gripper if part["part"] == "gripper" else self.style.robot
            if part["shape"] == "box":
                gtype, size = mujoco.mjtGeom.mjGEOM_BOX, np.asarray(part["size"], float)
            else:
                gtype = mujoco.mjtGeom.mjGEOM_CAPSULE
                size = np.array([part["size"][0], part["size"][1], 0.0])
            mujoco.mjv_initGeom(g, int(gtype), size, np.asarray(part["pos"], float),
                                np.asarray(part["rot"], float).ravel(), _rgba(colour))
            g.objtype, g.objid, g.segid = int(mujoco.mjtObj.mjOBJ_UNKNOWN), _ROBOT_OBJID, scene.ngeom
            scene.ngeom += 1

    def __call__(self, k: int, state: MjState) -> None:
        """Render frame ``k`` (colour, depth, segmentation) from ``state = (model, data)``.

        Raises:
            RenderingUnavailable: on the first frame, when no off-screen OpenGL back-end works.
        """
        m, d = state
        mujoco = import_mujoco()
        t0 = time.perf_counter()
        if self.ctx is None:
            self._setup(m)
            self.setup_seconds = time.perf_counter() - t0
        self.gl.make_current()
        scn, flags = self.scene, mujoco.mjtRndFlag
        mujoco.mjv_updateScene(m, d, self.opt, None, self.cam, int(mujoco.mjtCatBit.mjCAT_ALL), scn)
        if self.style.show_robot:
            self._add_robot(scn, np.array(d.mocap_pos[0]))
        scn.flags[flags.mjRND_SHADOW] = 0
        scn.flags[flags.mjRND_REFLECTION] = 0
        # pass 1: colour and depth
        mujoco.mjr_render(self.rect, scn, self.ctx)
        mujoco.mjr_readPixels(self._buf_rgb, self._buf_depth, self.rect, self.ctx)
        self.rgb[k] = self._buf_rgb[::-1]
        self.depth[k] = (self._d / (self._buf_depth[::-1].astype(np.float64) + self._c)).astype(np.float32)
        # pass 2: segmentation (each geom drawn in a colour encoding segid + 1; 0 = nothing)
        scn.flags[flags.mjRND_SEGMENT] = 1
        scn.flags[flags.mjRND_IDCOLOR] = 1
        mujoco.mjr_render(self.rect, scn, self.ctx)
        scn.flags[flags.mjRND_SEGMENT] = 0
        scn.flags[flags.mjRND_IDCOLOR] = 0
        mujoco.mjr_readPixels(self._buf_rgb, None, self.rect, self.ctx)
        ids = self._buf_rgb[::-1].astype(np.int64)
        ids = ids[..., 0] + (ids[..., 1] << 8) + (ids[..., 2] << 16)
        lut = np.zeros(scn.ngeom + 2, np.uint8)
        flex = int(mujoco.mjtObj.mjOBJ_FLEX)
        for i in range(scn.ngeom):
            g = scn.geoms[i]
            if 0 <= g.segid <= scn.ngeom:
                lab = (SEG_OBJECT if g.objtype == flex else
                       SEG_ROBOT if g.objid == _ROBOT_OBJID else SEG_BACKGROUND)
                lut[g.segid + 1] = lab
        self.segmentation[k] = lut[np.clip(ids, 0, len(lut) - 1)]
        self.seconds += time.perf_counter() - t0

    def close(self) -> None:
        """Free the MuJoCo render context and the GL context (safe to call twice)."""
        if self.ctx is not None:
            if self.gl is not None:
                self.gl.make_current()
            self.ctx.free()
            self.ctx = None
        if self.gl is not None:
            self.gl.free()
            self.gl = None
