"""``newton-cloth``: importing Newton lazily and building the cloth worlds of one model.

* :func:`import_newton`: ``(newton, warp)``, imported on the first simulation only, or one line
  naming ``pip install "softsbi[newton]"``;
* :func:`membrane_lame` and :func:`bend_edge_stiffness`: the one mapping from the shared physical
  parameters (``stretch`` [N/m], ``bend`` [N m]) to Newton's VBD cloth knobs;
* :func:`build_cloth_world`: one square cloth grid, its table plane and its kinematic handles, added
  to a ``newton.ModelBuilder`` as one world (a batch adds one world per parameter set).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from softsbi.backends.common import grid_faces
from softsbi.backends.scenario_build import grid_rest_vertices, handle_vertices
from softsbi.core.errors import DependencyMissing, ParameterError
from softsbi.core.types import Scenario

#: the Newton release this backend was written and measured against (the ``newton`` extra pins it)
NEWTON_VERSION = "1.8.0"
#: the one-line fix when Newton is missing
INSTALL_HINT = 'pip install "softsbi[newton]"'


def import_newton() -> tuple[Any, Any]:
    """``(newton, warp)``, imported now (not when softsbi is imported); Warp's per-module load lines are silenced.

    Raises:
        DependencyMissing: Newton or Warp is not installed (names :data:`INSTALL_HINT`).
    """
    try:
        import warp as wp  # optional: the 'newton' extra
        wp.config.log_level = wp.LOG_WARNING  # no line per kernel module loaded (Warp logs them at INFO)
        import newton  # optional: the 'newton' extra
    except ImportError as exc:
        raise DependencyMissing(f"backend 'newton-cloth' needs Newton {NEWTON_VERSION} (and Warp), which is not "
                                f"installed ({exc}): {INSTALL_HINT}") from exc
    return newton, wp


def membrane_lame(stretch: float, poisson: float) -> tuple[float, float]:
    """2-D Lamé parameters ``(mu, lambda)`` [N/m] of a plane-stress membrane of stretch stiffness
    ``stretch = E t`` [N/m] and Poisson ratio ``poisson``: ``mu = k / (2 (1 + nu))``,
    ``lambda = k nu / (1 - nu^2)``. Newton's VBD membrane (stable Neo-Hookean, ``tri_ke = mu``,
    ``tri_ka = lambda``) linearises to exactly this membrane.

    Raises:
        ParameterError: ``stretch`` not > 0 or ``poisson`` outside [0, 0.5).
    """
    if not stretch > 0:
        raise ParameterError(f"stretch must be > 0 N/m, got {stretch}")
    if not 0.0 <= poisson < 0.5:
        raise ParameterError(f"poisson must lie in [0, 0.5), got {poisson}")
    return stretch / (2.0 * (1.0 + poisson)), stretch * poisson / (1.0 - poisson ** 2)


def bend_edge_stiffness(bend: float, spacing: float) -> float:
    """Newton's VBD hinge stiffness ``edge_ke`` [N m / m] for bending rigidity ``bend = D`` [N m] on a
    grid of ``spacing`` h [m]: ``D / h``.

    VBD's hinge energy is ``ke |e| (theta - theta0)^2 / 2`` per interior edge. A grid bent into a
    cylinder of curvature ``kappa`` across one grid axis folds only the edges along the other axis,
    each by ``theta = kappa h`` (length ``h``, one per ``h^2`` of cloth), storing
    ``ke h kappa^2 / 2`` per m^2; the plate stores ``D kappa^2 / 2``. Checked by the clamped-strip
    droop (tests/backends/test_backend_units.py).

    Raises:
        ParameterError: ``bend`` or ``spacing`` not > 0.
    """
    if not bend > 0 or not spacing > 0:
        raise ParameterError(f"bend and spacing must be > 0 (got {bend} N m, {spacing} m)")
    return bend / spacing


@dataclass
class ClothWorld:
    """What the stepping loop needs of one cloth world (one parameter set).

    Attributes:
        rest: ``(N, 3)`` m rest positions (the cloth lies ``radius`` above the table).
        handles: grasped vertex of each handle, in ``scenario.handles`` order.
        mass: ``(N,)`` kg lumped vertex masses (handles included, though they move kinematically).
        spacing: grid spacing h, m.
    """

    rest: np.ndarray
    handles: list[int]
    mass: np.ndarray
    spacing: float


def build_cloth_world(newton: Any, wp: Any, scenario: Scenario, theta: Mapping[str, float], *, grid: int,
                      radius: float, poisson: float, damping: float, contact_ke: float) -> tuple[Any, ClothWorld]:
    """A ``newton.ModelBuilder`` holding one cloth world: the ``grid x grid`` cloth (vertex ``i * grid + j``,
    :func:`~softsbi.backends.scenario_build.grid_rest_vertices`, triangles
    :func:`~softsbi.backends.common.grid_faces`), the table plane at ``scenario.table_z`` and every
    handle's vertex made kinematic (mass 0: the loop moves it).

    ``theta``: ``bend`` [N m], ``stretch`` [N/m], ``friction`` [1], ``scale`` [m], ``mass`` [kg/m^2]
    (optionally ``yaw`` [deg]). Damping: Rayleigh, ``damping`` s times each stiffness. Friction:
    Newton mixes the particle and shape coefficients as ``sqrt(mu_p mu_s)``; the model's particle
    coefficient is 1 (:func:`finish_model`) and the table's is ``friction^2``, so each world has its own
    friction. Contact stiffness ``contact_ke`` N/m.
    """
    L = float(theta["scale"])
    h = L / (grid - 1)
    z0 = float(scenario.table_z) + radius
    rest = grid_rest_vertices(scenario, L, grid, z0, theta)
    faces = grid_faces(grid)
    mu, lam = membrane_lame(float(theta["stretch"]), poisson)
    ke = bend_edge_stiffness(float(theta["bend"]), h)
    b = newton.ModelBuilder(gravity=tuple(float(g) for g in scenario.gravity))
    b.add_cloth_mesh(pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0, 0.0, 0.0),
                     vertices=[wp.vec3(*map(float, p)) for p in rest], indices=faces.ravel().tolist(),
                     density=float(theta["mass"]), tri_ke=mu, tri_ka=lam, tri_kd=damping * mu, edge_ke=ke,
                     edge_kd=damping * ke, particle_radius=radius)
    cfg = b.default_shape_cfg.copy()
    cfg.mu = float(theta["friction"]) ** 2
    cfg.ke = contact_ke
    b.add_ground_plane(height=float(scenario.table_z), cfg=cfg)
    mass = np.asarray(b.particle_mass, dtype=float).copy()
    hv = handle_vertices(scenario, rest, grid)
    for v in hv:
        b.particle_mass[v] = 0.0
    return b, ClothWorld(rest=rest, handles=hv, mass=mass, spacing=h)


def finish_model(newton: Any, worlds: list[Any], gravity: Any, device: str, contact_ke: float) -> Any:
    """One ``newton.Model`` holding every builder of ``worlds`` as its own world (world ``b`` = parameter
    set ``b``; particles ``b * N .. (b + 1) * N - 1``), coloured for VBD (bending included)."""
    main = newton.ModelBuilder(gravity=tuple(float(g) for g in gravity))
    for w in worlds:
        main.add_world(w)
    main.color(include_bending=True)
    model = main.finalize(device=device)
    model.soft_contact_mu = 1.0
    model.soft_contact_ke = contact_ke
    return model

