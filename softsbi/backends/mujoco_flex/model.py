"""``mujoco-flex`` model: the MuJoCo scene as a plain dict (:func:`build_spec`, :func:`build_rope_spec`)
and its MJCF text (:func:`spec_to_xml`). No MuJoCo import here; the simulator compiles the XML.

Cloth (lift, wipe, fling; ~10 ms to compile):

* ``<flexcomp type="grid" dim="2">`` of ``grid x grid`` vertices, side ``scale`` m, total
  mass ``mass * scale^2`` kg, with ``<elasticity elastic2d="both">`` (membrane + bending; MuJoCo
  docs, XML reference *flexcomp/elasticity*). MuJoCo 4.0 removed ``<composite>``; flex
  elasticity rejects the implicit integrators, hence ``integrator="discrete"`` by default.
* grasp: a mocap body ``grip`` and ``<equality><connect body1="cloth_<corner>" body2="grip">``
  (mocap attachments to an elastic flex are rejected by MuJoCo 4.0).
* table: a plane at ``scenario.table_z``; the cloth lies flat on it at t = 0 with the grasped
  corner at ``object["corner"]`` and its diagonal along ``object["direction"]`` (rotated by
  ``theta["yaw"]`` when sampled), ``radius`` above the table.

Rope (wind): a 1-D ``flexcomp`` of ``nodes`` vertices with inextensible edges, and the spool as a
fixed cylinder geom (:func:`build_rope_spec`).

Physical parameters -> MuJoCo (plate theory, Kirchhoff-Love; ``nu`` = ``poisson``, fixed)::

    stretch  k = E t                      [N/m]   membrane stiffness
    bend     D = E t^3 / (12 (1 - nu^2))  [N m]   bending rigidity
    =>  thickness t = sqrt(12 (1 - nu^2) D / k),   young E = k / t

``friction`` is the sliding friction coefficient of the cloth-table contact (both the table geom
and the flex contact get it; MuJoCo combines by maximum). ``mass`` is the areal density in
kg/m^2 (the ten fabrics measured by Wang et al. 2011, shipped in ``shared/data/fabric_materials``,
range 0.113-0.324 kg/m^2). ``scale`` is the cloth side in metres.

Extending (effects): :func:`build_spec` returns a plain nested dict; an effect edits it before
:func:`spec_to_xml`, e.g. ``spec["option"].update(density=1.2, viscosity=1.8e-5, wind="1 0 0")``
or ``spec["flexcomp"]["inertiabox"] = h``; rendering adds ``spec["render"]`` (camera, light,
``<visual>`` settings; no physics effect). Two keys are not MJCF but are read by the simulator: ``spec["motion"]``
(``time_scale``: the commanded paths take that many times the scenario's duration) and ``spec["rest"]`` (the
vertices at rest), with ``spec["connects"]`` (the handles' constraints; more may be added to the ``grip`` mocap):
:func:`add_motion`, :func:`add_handles`. What MJCF cannot say is applied to the compiled model:
``spec["anisotropy"] = {"warp_weft_ratio": r}`` makes the cloth's membrane orthotropic (:func:`apply_anisotropy`,
which the simulator calls after compiling; it is not in the XML text), about the warp axis ``spec["warp"]``.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from softsbi.backends.common import size_params
from softsbi.backends.scenario_build import (friction_words, grid_rest_vertices, handle_vertices, mesh_rest,
                                             obstacles)
from softsbi.core.errors import ParameterError
from softsbi.core.types import Param, ParamSpace, Scenario
from softsbi.scenarios.builtin import placed_direction

#: default areal density (kg/m^2) used when ``mass`` is not sampled: camel-ponte-roma, DiffCloud's start
DEFAULT_AREAL_DENSITY = 0.284


def _fmt(v: Any) -> str:
    if isinstance(v, (list, tuple, np.ndarray)):
        return " ".join(_fmt(x) for x in (v.ravel().tolist() if isinstance(v, np.ndarray) else v))
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return str(v)


def plate_mapping(bend: float, stretch: float, poisson: float) -> tuple[float, float]:
    """Map bending rigidity ``D`` (N m) and stretch stiffness ``k`` (N/m) to MuJoCo ``(young, thickness)``.

    ``t = sqrt(12 (1 - nu^2) D / k)`` (m), ``E = k / t`` (Pa), so that ``E t = k`` and
    ``E t^3 / (12 (1 - nu^2)) = D``. ``bend`` and ``stretch`` have the same meaning on every backend
    (:func:`softsbi.backends.common.cloth_material_params`). Measured (clamped strip,
    :func:`~softsbi.backends.common.cantilever_scenario`, small deflection): the flex droops 2.0x the
    Euler-Bernoulli value at a 9x9 grid and 1.5x at 17x17 (discretisation, converging; the backend-units
    suite, docs/benchmarks.md).

    Raises:
        ParameterError: ``bend`` or ``stretch`` not > 0.
    """
    if bend <= 0 or stretch <= 0:
        raise ParameterError(f"bend and stretch must be > 0 (got {bend}, {stretch})")
    t = math.sqrt(12.0 * (1.0 - poisson ** 2) * bend / stretch)
    return stretch / t, t



def build_spec(scenario: Scenario, theta: Mapping[str, float], *, grid: int, timestep: float, solver: str,
               integrator: str, poisson: float, radius: float, damping: float, iterations: int,
               overrides: Mapping[str, float] | None = None) -> dict[str, Any]:
    """The cloth model as a nested dict (``option``, ``flexcomp``, ``elasticity``, ``contact``, ``table``,
    ``grip``, ``corner_body``, ``connect``); units SI (m, kg, s, Pa). ``theta`` needs ``bend`` [N m],
    ``stretch`` [N/m], ``friction``, ``scale`` [m], optionally ``mass`` [kg/m^2] (default
    :data:`DEFAULT_AREAL_DENSITY`) and ``yaw`` [deg]; ``grid`` vertices per side, ``timestep`` s,
    ``radius`` m. ``overrides`` replaces derived MuJoCo values (``young``, ``thickness``,
    ``timestep``, ``damping``, any other key goes to ``option``) bypassing the bounds (testing only).

    Raises:
        ParameterError: ``bend`` or ``stretch`` not > 0. KeyError: a required ``theta`` key is missing
            (the simulator checks ``theta`` first).
    """
    ov = dict(overrides or {})
    timestep = float(ov.pop("timestep", timestep))
    obj = scenario.object
    L = float(theta["scale"])
    rho = float(theta.get("mass", DEFAULT_AREAL_DENSITY))
    young, thick = plate_mapping(float(theta["bend"]), float(theta["stretch"]), poisson)
    young = float(ov.pop("young", young))
    thick = float(ov.pop("thickness", thick))
    d = placed_direction(scenario, theta)
    corner = np.asarray(obj.get("corner", scenario.gripper[0, :2]), dtype=float)
    # vertex 0 of the grid sits at local (-L/2, -L/2); the local diagonal (1, 1)/sqrt2 must map to d
    phi = math.degrees(math.atan2(d[1], d[0])) - 45.0
    centre = corner + d * L / math.sqrt(2.0)
    z0 = float(scenario.table_z) + radius
    h = L / (grid - 1)
    fric = float(theta["friction"])
    if "mesh" in obj:  # a mesh cloth at its placement (scale and yaw about the pivot vertex)
        rest, faces = mesh_rest(scenario, theta, z0)
        centre = rest[:, :2].mean(0)
        area = float(0.5 * np.linalg.norm(np.cross(rest[faces[:, 1]] - rest[faces[:, 0]],
                                                    rest[faces[:, 2]] - rest[faces[:, 0]]), axis=1).sum())
        flex = {"name": "cloth", "type": "direct", "dim": 2, "radius": radius, "mass": rho * area,
                "point": rest.ravel().tolist(), "element": faces.ravel().tolist()}
        tri = 0.5 * np.linalg.norm(np.cross(rest[faces[:, 1]] - rest[faces[:, 0]], rest[faces[:, 2]] - rest[faces[:, 0]]),
                                   axis=1)
        varea = np.zeros(len(rest))
        np.add.at(varea, faces.ravel(), np.repeat(tri / 3.0, 3))
        e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        e = np.unique(e, axis=0)
        # what effects need of a mesh (a grid has it in its flexcomp attributes): mean edge length, the
        # surface patch of each vertex (a third of its triangles' areas)
        layout = {"spacing": float(np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1).mean()),
                  "n": len(rest), "area": varea.tolist()}
        yaw = math.radians(float(theta.get("yaw", 0.0)))  # mesh_rest turns the mesh's own x axis by the yaw
        warp = [math.cos(yaw), math.sin(yaw), 0.0]
    else:
        rest = grid_rest_vertices(scenario, L, grid, z0, theta)
        layout = None
        warp = [math.cos(math.radians(phi)), math.sin(math.radians(phi)), 0.0]  # the grid's first axis (index i)
        flex = {"name": "cloth", "type": "grid", "dim": 2, "count": [grid, grid, 1],
                "spacing": [h, h, h], "pos": [float(centre[0]), float(centre[1]), z0],
                "euler": [0.0, 0.0, phi], "radius": radius, "mass": rho * L * L}
    spec = {
        "option": {"timestep": timestep, "solver": solver, "integrator": integrator,
                   "iterations": iterations, "gravity": scenario.gravity},
        "table": {"name": "table", "type": "plane", "size": [2.0, 2.0, 0.01],
                  "pos": [float(centre[0]), float(centre[1]), float(scenario.table_z)],
                  "friction": [fric, 0.005, 0.0001], "condim": 3},
        "geoms": obstacle_geoms(scenario, fric),
        "flexcomp": flex,
        "contact": {"condim": 3, "friction": [fric, 0.005, 0.0001], "selfcollide": "none",
                    "solref": [0.004, 1.0]},
        "edge": {"equality": "false"},
        "elasticity": {"young": young, "poisson": poisson, "thickness": thick,
                       "damping": float(ov.pop("damping", damping)), "elastic2d": "both"},
    }
    if layout is not None:
        spec["mesh_layout"] = layout
    spec["warp"] = warp  # the cloth's material x axis (warp) in the world at rest, unit (3,): see apply_anisotropy
    add_handles(spec, scenario, rest, handle_vertices(scenario, rest, grid), "cloth", timestep)
    add_motion(spec, rest)
    for k, v in ov.items():  # remaining overrides go to option
        spec["option"][k] = v
    return spec


def orthotropic_stiffness(rest: np.ndarray, elements: np.ndarray, warp: np.ndarray, stretch: float, poisson: float,
                          ratio: float) -> np.ndarray:
    """MuJoCo's per-triangle membrane stiffness (``mjModel.flex_stiffness`` of a 2-D flex, the upper triangle of a 3x3
    matrix over each triangle's edges) for an orthotropic membrane; at ``ratio = 1`` it is MuJoCo's own isotropic
    one (Saint Venant-Kirchhoff, plane stress, to machine precision: ``tests/effects/test_rig.py``).

    The membrane (Huber's orthotropic plate): stiffness ``stretch * sqrt(ratio)`` N/m along the warp,
    ``stretch / sqrt(ratio)`` along the weft, their geometric mean ``stretch``; the Poisson coupling and the shear
    stiffness are the isotropic ones of ``stretch`` (``nu stretch / (1 - nu^2)``, ``stretch / (2 (1 + nu))``). So
    the plane-stress matrix ``C`` (N/m, Voigt with engineering shear) is ``stretch / (1 - nu^2) [[sqrt r, nu, 0],
    [nu, 1 / sqrt r, 0], [0, 0, (1 - nu) / 2]]``, positive definite for every ``r > 0``.

    Per triangle of rest area A with rest edges ``E_e`` (its vertices' order ``(1, 2), (2, 0), (0, 1)``, as
    MuJoCo's element edges), in the material frame (warp projected onto the triangle's plane, weft = normal x
    warp): an edge's squared-length change is ``delta_e = 2 E_e^T eps E_e`` for the Green strain ``eps``, i.e.
    ``delta = S eps_v``; the energy ``A/2 eps_v^T C eps_v`` is MuJoCo's ``delta^T K delta / 4`` for
    ``K = 2 A S^-T C S^-1``.

    Args:
        rest: ``(N, 3)`` rest vertex positions, m. elements: ``(F, 3)`` vertex indices. warp: ``(3,)`` the warp
            direction in the world at rest. stretch: the membrane stiffness ``E t``, N/m. poisson: nu.
        ratio: warp-to-weft stiffness ratio (> 0).

    Returns:
        ``(F, 6)``: each triangle's ``K`` in MuJoCo's order ``K00, K01, K02, K11, K12, K22``.
    """
    s, nu = math.sqrt(float(ratio)), float(poisson)
    C = float(stretch) / (1.0 - nu * nu) * np.array([[s, nu, 0.0], [nu, 1.0 / s, 0.0], [0.0, 0.0, (1.0 - nu) / 2.0]])
    P = np.asarray(rest, float)[np.asarray(elements, int)]                       # (F, 3 vertices, 3)
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    n /= 2.0 * area[:, None]
    w = np.asarray(warp, float)[None, :]
    a = w - (n @ w[0])[:, None] * n                                               # warp in each triangle's plane
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(n, a)
    E = P[:, [2, 0, 1]] - P[:, [1, 2, 0]]                                         # (F, 3 edges, 3): v1->v2, v2->v0, v0->v1
    ex, ey = np.einsum("fec,fc->fe", E, a), np.einsum("fec,fc->fe", E, b)
    S = 2.0 * np.stack([ex * ex, ey * ey, ex * ey], axis=-1)                      # (F, 3, 3): delta = S eps_v
    T = np.linalg.inv(S)
    K = 2.0 * area[:, None, None] * np.einsum("fji,jk,fkl->fil", T, C, T)
    iu = np.triu_indices(3)
    return K[:, iu[0], iu[1]]


def apply_anisotropy(m: Any, d: Any, spec: Mapping[str, Any]) -> None:
    """Make a compiled cloth's membrane orthotropic as ``spec["anisotropy"]`` asks (``{"warp_weft_ratio": r}``; no
    key, or ``r == 1``: nothing changes), writing :func:`orthotropic_stiffness` into ``m.flex_stiffness``. MuJoCo
    integrates the edited stiffness as its own (implicitly under ``integrator="discrete"``; the elasticity's Rayleigh
    damping scales with it). Call it after ``mj_forward`` at the rest state (``d.flexvert_xpos`` is the rest shape).

    Raises:
        ParameterError: a rope (no membrane), a cloth without membrane elasticity, or a MuJoCo whose compiled
            isotropic stiffness is not the one :func:`orthotropic_stiffness` computes at ratio 1 (another layout:
            the edit would be wrong, so it is refused).
    """
    r = float((spec.get("anisotropy") or {}).get("warp_weft_ratio", 1.0))
    if r == 1.0:
        return
    if int(m.flex_dim[0]) != 2 or int(m.flex_stiffnessadr[0]) < 0:
        raise ParameterError("an anisotropic membrane needs a cloth (a 2-D flex with membrane elasticity)")
    el = spec["elasticity"]
    stretch, nu = float(el["young"]) * float(el["thickness"]), float(el["poisson"])
    nel, adr = int(m.flex_elemnum[0]), int(m.flex_elemdataadr[0])
    elements = np.asarray(m.flex_elem[adr:adr + 3 * nel]).reshape(nel, 3)
    v0 = int(m.flex_vertadr[0])
    rest = np.asarray(d.flexvert_xpos).reshape(-1, 3)[v0:v0 + int(m.flex_vertnum[0])]
    start = int(m.flex_stiffnessadr[0])
    K = np.array(m.flex_stiffness[start:start + 21 * nel], dtype=float).reshape(nel, 21)
    iso = orthotropic_stiffness(rest, elements, spec["warp"], stretch, nu, 1.0)
    if not np.allclose(K[:, :6], iso, rtol=1e-9, atol=1e-12 * np.abs(iso).max()):
        raise ParameterError("this MuJoCo's flex membrane stiffness is not the one the anisotropic membrane was "
                             "derived from (mjModel.flex_stiffness layout); the anisotropy cannot be applied")
    K[:, :6] = orthotropic_stiffness(rest, elements, spec["warp"], stretch, nu, r)
    m.flex_stiffness[start:start + 21 * nel] = K.ravel()


def rope_param_space(scenario: Scenario) -> ParamSpace:
    """Parameters of a rope scenario (the winding), SI units: ``young`` = Young's modulus E of the rope
    material [Pa] (log 1e5-3e7): MuJoCo's ``young`` of the 1-D flex elasticity, whose bending rigidity
    is ``EI = E pi r^4 / 4`` for the rope radius ``r`` (checked by a clamped rope drooping under its
    weight, :func:`~softsbi.backends.common.rope_cantilever_scenario`; the rope is inextensible through ``<edge equality="true"/>``,
    so there is no ``stretch``); ``friction`` [1] 0.1-1.0 (on the table and the scenario's obstacles, described by
    name: :func:`~softsbi.backends.scenario_build.friction_words`), ``scale`` = rope length [m] 0.3-0.5,
    ``mass`` = linear density [kg/m] 0.01-0.05. The rope's stiffness was called ``bend`` before; that
    name means the cloth's bending rigidity D [N m] and is refused on a rope (:func:`check_rope_theta`)."""
    return ParamSpace([
        Param("young", 1e5, 3e7, "Pa", log=True,
              description="Young's modulus of the rope (bending rigidity E pi r^4 / 4; edges inextensible)"),
        Param("friction", 0.1, 1.0, "1", description=friction_words(scenario, "rope")),
        *size_params(None, rope=True),
    ])


def check_rope_theta(theta: Mapping[str, float]) -> None:
    """Refuse the rope's old parameter name ``bend`` with one line naming the rename.

    Raises:
        ParameterError: ``theta`` has ``bend`` (now ``young``, the same value in Pa).
    """
    if "bend" in theta:
        raise ParameterError(f"the mujoco-flex rope's stiffness is now 'young' (Young's modulus, Pa; the same value "
                             f"as the old 'bend' = {theta['bend']}); 'bend' is the cloth's bending rigidity in N*m. "
                             f"Rename it in your theta")


def rope_bending_rigidity(young: float, radius: float) -> float:
    """Bending rigidity ``EI`` [N m^2] of a rope of circular cross-section: ``young * pi * radius^4 / 4``
    (Young's modulus [Pa] times the second moment of area of a disc of ``radius`` m)."""
    return float(young) * math.pi * float(radius) ** 4 / 4.0


def build_rope_spec(scenario: Scenario, theta: Mapping[str, float], *, nodes: int, timestep: float, solver: str,
                    integrator: str, poisson: float, damping: float, iterations: int,
                    overrides: Mapping[str, float] | None = None) -> dict[str, Any]:
    """Model dict of the rope (``winding``) scenario, same keys as :func:`build_spec` plus ``geoms``
    (the spool). The rope is a 1-D ``flexcomp`` grid of ``nodes`` vertices with
    ``<edge equality="true"/>`` (MuJoCo 4.0: a 1-D flex explodes without it, shared/MEASURED.md) and
    ``<elasticity young=young>``; vertex 0 (body ``rope_0``) is grasped at ``object["start"]`` and the
    rope lies along ``object["direction"]``. The spool is a fixed vertical cylinder geom.
    ``theta``: ``young`` [Pa], ``friction``, ``scale`` (length) [m], ``mass`` [kg/m].

    Raises:
        KeyError: a required ``theta`` key is missing (the simulator checks ``theta`` first).
    """
    ov = dict(overrides or {})
    timestep = float(ov.pop("timestep", timestep))
    obj = scenario.object
    L = float(theta["scale"])
    r = float(obj.get("radius", 0.004))
    e = np.asarray(obj.get("direction", (0.0, -1.0)), dtype=float)
    e = e / np.linalg.norm(e)
    start = np.asarray(obj.get("start", scenario.gripper[0, :2]), dtype=float)
    centre = start + e * L / 2.0
    z0 = float(scenario.table_z) + r
    h = L / (nodes - 1)
    fric = float(theta["friction"])
    spec: dict[str, Any] = {
        "option": {"timestep": timestep, "solver": solver, "integrator": integrator,
                   "iterations": iterations, "gravity": scenario.gravity},
        "table": {"name": "table", "type": "plane", "size": [2.0, 2.0, 0.01],
                  "pos": [0.0, 0.0, float(scenario.table_z)], "friction": [fric, 0.005, 0.0001], "condim": 3},
        "geoms": obstacle_geoms(scenario, fric),
        "flexcomp": {"name": "rope", "type": "grid", "dim": 1, "count": [nodes, 1, 1], "spacing": [h, h, h],
                     "pos": [float(centre[0]), float(centre[1]), z0],
                     "euler": [0.0, 0.0, math.degrees(math.atan2(e[1], e[0]))], "radius": r,
                     "mass": float(theta["mass"]) * L},
        "contact": {"condim": 3, "friction": [fric, 0.005, 0.0001], "selfcollide": "none", "solref": [0.004, 1.0]},
        "edge": {"equality": "true"},
        "elasticity": {"young": float(ov.pop("young", theta["young"])), "poisson": poisson,
                       "thickness": float(ov.pop("thickness", 2.0 * r)), "damping": float(ov.pop("damping", damping))},
    }
    rest = np.column_stack([start + np.linspace(0.0, L, nodes)[:, None] * e, np.full(nodes, z0)])
    add_handles(spec, scenario, rest, handle_vertices(scenario, rest), "rope", timestep)
    add_motion(spec, rest)
    for k, v in ov.items():
        spec["option"][k] = v
    return spec


def obstacle_geoms(scenario: Scenario, fric: float) -> list[dict[str, Any]]:
    """MuJoCo geoms of the scenario's obstacles: a ``cylinder`` stands on the table (``centre`` [x, y],
    ``radius``, ``height`` m), a ``box`` has ``centre`` [x, y, z], ``half_size`` and ``yaw`` (deg)."""
    out = []
    for i, o in enumerate(obstacles(scenario)):
        name = o.get("name") or f"obstacle_{i}"
        if o["type"] == "cylinder":
            out.append({"name": name, "type": "cylinder", "size": [float(o["radius"]), float(o["height"]) / 2],
                        "pos": [float(o["centre"][0]), float(o["centre"][1]),
                                float(scenario.table_z) + float(o["height"]) / 2],
                        "friction": [fric, 0.005, 0.0001], "condim": 3})
        else:
            out.append({"name": name, "type": "box", "size": [float(v) for v in o["half_size"]],
                        "pos": [float(v) for v in o["centre"]], "euler": [0.0, 0.0, float(o.get("yaw", 0.0))],
                        "friction": [fric, 0.005, 0.0001], "condim": 3})
    return out


def add_handles(spec: dict[str, Any], scenario: Scenario, rest: np.ndarray, vertices: list[int], body: str,
                timestep: float) -> None:
    """One mocap body per handle at its grasped vertex's rest position, welded to the vertex's body by an
    ``<equality><connect>`` (pinned handles are mocaps that never move). The first moving handle's mocap
    is ``spec["grip"]`` (mocap index 0, named ``grip``) and its constraint ``spec["connect"]`` (what the
    grip-compliance effect edits); all of them are in ``spec["grips"]`` / ``spec["connects"]`` (handle
    order in ``spec["handle_mocaps"]``: the mocap index of each handle)."""
    first = next(i for i, h in enumerate(scenario.handles) if not h.pinned)
    order = [first] + [i for i in range(len(scenario.handles)) if i != first]
    grips, connects, mocap_of = [], [], [0] * len(order)
    for j, i in enumerate(order):
        h = scenario.handles[i]
        name = "grip" if j == 0 else f"handle_{i}"
        p = rest[vertices[i]]
        grips.append({"name": name, "mocap": "true", "pos": [float(p[0]), float(p[1]), float(p[2])]})
        # stiff grasp: solref time constant at twice the step (MuJoCo's minimum for stability)
        connects.append({"body1": f"{body}_{vertices[i]}", "body2": name, "anchor": [0.0, 0.0, 0.0],
                         "solref": [2.0 * float(timestep), 0.4], "solimp": [0.99, 0.999, 0.001, 0.5, 2.0]})
        mocap_of[i] = j
        del h
    spec.update(grip=grips[0], grips=grips, connect=connects[0], connects=connects,
                corner_body=connects[0]["body1"], handle_mocaps=mocap_of, handle_vertices=list(vertices))


def add_motion(spec: dict[str, Any], rest: np.ndarray) -> None:
    """The parts of the model dict that effects may edit and MJCF does not hold: ``spec["rest"]``, the object's
    vertices at rest ``(N, 3)`` m as nested lists (vertex order of the flex), and ``spec["motion"]``, how the
    simulator executes the scenario's commanded paths: ``time_scale`` (1.0: each path takes the scenario's
    duration; ``s``: it takes ``s`` times as long and the frames are recorded at the same fractions of the motion,
    :meth:`~softsbi.backends.mujoco_flex.simulator.MujocoFlex.simulate`)."""
    spec["rest"] = np.asarray(rest, dtype=float).tolist()
    spec["motion"] = {"time_scale": 1.0}


def spec_to_xml(spec: Mapping[str, Any]) -> str:
    """Serialise the dict of :func:`build_spec` / :func:`build_rope_spec` (plus ``spec["render"]``, if a
    renderer added one) to an MJCF string; lists become space-separated values, bools true/false.

    Raises:
        KeyError: a required section (``option``, ``table``, ``grip``, ``flexcomp``, ...) is missing.
    """
    def attrs(d: Mapping[str, Any]) -> str:
        return " ".join(f'{k}="{_fmt(v)}"' for k, v in d.items())
    fc = spec["flexcomp"]
    # rendering only (simulate_images): <visual> settings, a camera and a light; no physics effect
    rnd = spec.get("render") or {}
    visual = "".join(f"<{k} {attrs(v)}/>" for k, v in rnd.get("visual", {}).items())
    visual = f"\n  <visual>{visual}</visual>" if visual else ""
    extras = "".join(f"<{k} {attrs(v)}/>" for k, v in rnd.get("bodies", []))
    return f"""<mujoco model="softsbi_lift">
  <compiler autolimits="true"/>
  <option {attrs(spec["option"])}/>{visual}
  <worldbody>{extras}
    <geom {attrs(spec["table"])}/>
    {"".join(f"<geom {attrs(g)}/>" for g in spec.get("geoms", []))}
    {"".join(f"<body {attrs(g)}/>" for g in spec.get("grips", [spec["grip"]]))}
    <flexcomp {attrs(fc)}>
      <contact {attrs(spec["contact"])}/>
      <edge {attrs(spec["edge"])}/>
      <elasticity {attrs(spec["elasticity"])}/>
    </flexcomp>
  </worldbody>
  <equality>
    {"".join(f"<connect {attrs(c)}/>" for c in spec.get("connects", [spec["connect"]]))}
  </equality>
</mujoco>
"""

