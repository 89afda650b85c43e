"""``mujoco-flex``: cloth (lift, wipe, fling) and rope (wind) simulated with MuJoCo 4.0 flex.

One concern per module:

* :mod:`.model`: the scene as a plain dict (:func:`build_spec`, :func:`build_rope_spec`), the
  plate-theory parameter mapping (:func:`plate_mapping`) and the MJCF text (:func:`spec_to_xml`);
* :mod:`.simulator`: :class:`MujocoFlex`, the plugin, and its one stepping loop;
* :mod:`.render`: :class:`MjFrameRenderer`, the per-frame renderer (colour, depth, segmentation)
  used by :meth:`~softsbi.core.interfaces.Simulator.simulate_images`;
* :mod:`.gl`: importing MuJoCo without OpenGL, and choosing the off-screen GL back-end.

The cloth grid layout and the visual-only robot are shared with ``pybullet-massspring``
(:mod:`softsbi.backends.common`) and re-exported here.
"""
from __future__ import annotations

from softsbi.backends.common import (ARM_LENGTH, ARM_RADIUS, GRIPPER_HALF, PROP_COLOUR, SHOULDER_HEIGHT, grid_corners,
                                     grid_faces, robot_base, visual_robot)
from softsbi.backends.mujoco_flex.model import (DEFAULT_AREAL_DENSITY, build_rope_spec, build_spec, plate_mapping,
                                                rope_bending_rigidity, rope_param_space, spec_to_xml)
from softsbi.backends.mujoco_flex.render import MjFrameRenderer, MjState
from softsbi.backends.mujoco_flex.simulator import MujocoFlex
from softsbi.core.interfaces import Simulator
from softsbi.plugins.hookspecs import hookimpl

__all__ = ["ARM_LENGTH", "ARM_RADIUS", "DEFAULT_AREAL_DENSITY", "GRIPPER_HALF", "PROP_COLOUR", "SHOULDER_HEIGHT",
           "MjFrameRenderer", "MjState", "MujocoFlex", "build_rope_spec", "build_spec", "grid_corners", "grid_faces",
           "plate_mapping", "robot_base", "rope_bending_rigidity", "rope_param_space", "softsbi_simulators", "spec_to_xml", "visual_robot"]


@hookimpl
def softsbi_simulators() -> list[type[Simulator]]:
    """The ``mujoco-flex`` simulator plugin."""
    return [MujocoFlex]
