"""``newton-cloth``: cloth (lift, wipe, fling) simulated with Newton's VBD solver on Warp (CPU or CUDA).

One concern per module:

* :mod:`.model`: importing Newton lazily (:func:`import_newton`), the mapping of the shared physical
  parameters to VBD's knobs (:func:`membrane_lame`, :func:`bend_edge_stiffness`) and the cloth worlds
  of one model (:func:`build_cloth_world`, :func:`finish_model`);
* :mod:`.simulator`: :class:`NewtonCloth`, the plugin, its stepping loop and batched rollouts
  (:meth:`NewtonCloth.simulate_batch`); its docstring says which solver and why.

Newton is optional (``pip install "softsbi[newton]"``, pinned to :data:`NEWTON_VERSION`): importing
this package does not import it.
"""
from __future__ import annotations

from softsbi.backends.newton_cloth.model import (INSTALL_HINT, NEWTON_VERSION, bend_edge_stiffness, build_cloth_world,
                                                 finish_model, import_newton, membrane_lame)
from softsbi.backends.newton_cloth.simulator import NewtonCloth
from softsbi.core.interfaces import Simulator
from softsbi.plugins.hookspecs import hookimpl

__all__ = ["INSTALL_HINT", "NEWTON_VERSION", "NewtonCloth", "bend_edge_stiffness", "build_cloth_world",
           "finish_model", "import_newton", "membrane_lame", "softsbi_simulators"]


@hookimpl
def softsbi_simulators() -> list[type[Simulator]]:
    """The ``newton-cloth`` simulator plugin."""
    return [NewtonCloth]
