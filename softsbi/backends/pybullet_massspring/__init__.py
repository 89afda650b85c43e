"""``pybullet-massspring``: cloth (lift, wipe, fling) and rope (wind) in PyBullet's deformable
world, mass-spring model (formerly ``pybullet-fem``; that name still resolves, with a warning).

One concern per module:

* :mod:`.model`: importing pybullet quietly, the rest meshes (:func:`cloth_vertices`,
  :func:`ribbon_vertices`), the substep rule and the world of one rollout (:func:`build_world`);
* :mod:`.simulator`: :class:`PybulletMassSpring`, the plugin, and its one stepping loop;
* :mod:`.render`: :class:`PbFrameRenderer` (TinyRenderer, CPU) and the camera matrices
  (:func:`gl_matrices`), used by :meth:`~softsbi.core.interfaces.Simulator.simulate_images`.

The cloth grid layout and the visual-only robot are shared with ``mujoco-flex``
(:mod:`softsbi.backends.common`).
"""
from __future__ import annotations

import warnings
from typing import Any

from softsbi.backends.common import grid_corners, grid_faces
from softsbi.backends.pybullet_massspring.model import (CLOTH_SCENARIOS, ROPE_SCENARIOS, STABILITY_C, build_world,
                                                        cloth_vertices, import_pybullet, ribbon_faces,
                                                        ribbon_vertices, substeps, write_obj)
from softsbi.backends.pybullet_massspring.render import FAR, NEAR, PbFrameRenderer, PbState, gl_matrices
from softsbi.backends.pybullet_massspring.simulator import PybulletMassSpring
from softsbi.core.interfaces import Simulator
from softsbi.plugins.hookspecs import hookimpl

__all__ = ["CLOTH_SCENARIOS", "FAR", "NEAR", "ROPE_SCENARIOS", "STABILITY_C", "PbFrameRenderer", "PbState",
           "PybulletMassSpring", "build_world", "cloth_vertices", "gl_matrices", "grid_corners", "grid_faces",
           "import_pybullet", "ribbon_faces", "ribbon_vertices", "softsbi_simulators", "substeps", "write_obj"]


@hookimpl
def softsbi_simulators() -> list[type[Simulator]]:
    """The ``pybullet-massspring`` simulator plugin."""
    return [PybulletMassSpring]


def __getattr__(name: str) -> Any:
    """``PybulletFEM``, the class's former name, still imports (with a FutureWarning).

    Raises:
        AttributeError: any other unknown name.
    """
    if name == "PybulletFEM":
        warnings.warn("softsbi.backends.pybullet_massspring.PybulletFEM is deprecated; use PybulletMassSpring "
                      "(the model is mass-spring, not FEM)", FutureWarning, stacklevel=2)
        return PybulletMassSpring
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
