"""Material candidate effects: what the nominal cloth's isotropic material leaves out.

``aniso-stretch``: a woven fabric is stiffer along its yarns in one direction than in the other (warp and weft);
the nominal membrane has one stretch stiffness in every direction. A model edit for ``mujoco-flex``: MJCF has no
anisotropic flex elasticity, so the backend writes the orthotropic membrane into the compiled model
(:func:`softsbi.backends.mujoco_flex.model.apply_anisotropy`).
"""
from __future__ import annotations

from typing import Any, ClassVar, Mapping

from softsbi.core.interfaces import Effect
from softsbi.core.types import Param, ParamSpace


class AnisotropicStretch(Effect):
    """A woven cloth's anisotropic stretch: the warp is stiffer (or softer) than the weft.

    Physics: the membrane is Huber's orthotropic plate. Its stretch stiffness is ``stretch * sqrt(r)`` N/m along
    the warp and ``stretch / sqrt(r)`` along the weft, ``r = warp_weft_ratio`` (dimensionless), so the nominal
    ``stretch`` stays their geometric mean; the Poisson coupling and the shear stiffness stay those of ``stretch``,
    and so does the bending rigidity (the effect changes stretching only). The warp is the cloth's material x
    axis: a grid cloth's first axis (vertex ``i * n + j``: index i), a mesh cloth's own x axis (turned by its
    placement yaw). Off at ``r = 1`` (the prior's midpoint in log scale: the prior is log-uniform over 1/4-4).

    Direction: at ``r > 1`` the cloth stretches less along the warp and more along the weft than the nominal
    cloth of the same ``stretch``: stretched uniformly along the warp it pulls back ``sqrt(r)`` times as hard,
    along the weft ``1/sqrt(r)`` times (MuJoCo's passive forces, exactly); lifted by a corner (5x5 grid, stretch
    10 N/m, r = 4) its warp edges stretch 1.0 % where the nominal's stretch 2.5 %, its weft edges 4.7 %
    (``tests/effects/test_rig.py``). A corner lift pulls along the diagonal, which is symmetric in warp and weft:
    ``r`` and ``1/r`` then give near mirror images of each other about the diagonal's vertical plane, and to first
    order in ``log r`` the hanging shape does not change, so the screening's finite difference at ``r = 1`` hardly
    sees the effect there (measured on a lift at stretch 10 N/m with ``r = 4`` hidden: the screening credited
    heavy-hem with 17 % of the residual, aniso-stretch with 4 %).

    Model edit for ``mujoco-flex`` only (the orthotropic stiffness written into the compiled flex, integrated
    implicitly as the engine's own elasticity).
    """

    name: ClassVar[str] = "aniso-stretch"
    description: ClassVar[str] = "anisotropic stretch: warp-to-weft ratio of the membrane stiffness"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)
    model_edits: ClassVar[tuple[str, ...]] = ("mujoco-flex",)
    objects: ClassVar[tuple[str, ...]] = ("cloth",)  # a rope has no membrane

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("warp_weft_ratio", 0.25, 4.0, "1", log=True, limits=(1e-3, 1e3),
                                 description="membrane stiffness along the warp over that along the weft "
                                             "(their geometric mean is the nominal stretch)")])

    def nominal(self) -> dict[str, float]:
        return {"warp_weft_ratio": 1.0}

    def edit_model(self, backend: str, model: Any, theta: Mapping[str, float], ctx: Mapping[str, Any]) -> None:
        """Ask the backend for the orthotropic membrane (``model["anisotropy"]``; nothing at the off value)."""
        r = float(theta["warp_weft_ratio"])
        if r != 1.0:
            model["anisotropy"] = {"warp_weft_ratio": r}


MATERIAL_EFFECTS = (AnisotropicStretch,)
