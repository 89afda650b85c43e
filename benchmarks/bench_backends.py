"""The backends suite: speed per backend x scenario x mesh size, softsbi's overhead over a raw engine loop,
throughput with one and two LocalExecutor workers, and memory over many consecutive rollouts.

Single-threaded engines; every timing is the median of ``--repeats`` runs (the overhead: of at least 5, interleaved
with the raw loop so machine load affects both alike).
"""
from __future__ import annotations

import argparse
import gc
import statistics
import time

import numpy as np

from softsbi.backends.mujoco_flex import MujocoFlex, spec_to_xml
from softsbi.backends.pybullet_massspring import PybulletMassSpring
from softsbi.scenarios.builtin import SCENARIOS, make_scenario
from softsbi.executors.local import LocalExecutor

from benchmarks.runner import table

BACKENDS = {"mujoco-flex": MujocoFlex, "pybullet-massspring": PybulletMassSpring}


FULL = {"grids": [7, 11], "repeats": 3, "n_throughput": 16, "n_memory": 500}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--grids", type=int, nargs="+", default=[7], help="cloth grids (rope: 2 grid + 2 nodes)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--n-throughput", type=int, default=8, help="rollouts per throughput measurement")
    ap.add_argument("--n-memory", type=int, default=100, help="consecutive rollouts of the memory measurement")
    ap.add_argument("--only", nargs="+", default=["speed", "overhead", "throughput", "memory"],
                    choices=["speed", "overhead", "throughput", "memory"])


def suite(a: argparse.Namespace) -> dict:
    tables = []
    if "speed" in a.only:
        tables.append(table(f"Wall time per simulated second, prior midpoint, median of {a.repeats}",
                            ["backend", "scenario", "mesh", "vertices", "wall s / sim s"], speed(a.grids, a.repeats)))
    if "overhead" in a.only:
        g, r = a.grids[0], max(a.repeats, 5)
        tables.append(table(f"softsbi rollout against a raw engine loop (lift {g}x{g}), median of {r}",
                            ["backend", "softsbi s", "raw s", "overhead %"], overhead(g, r)))
    if "throughput" in a.only:
        g = a.grids[0]
        tables.append(table(f"Throughput, {a.n_throughput} lift rollouts ({g}x{g}), LocalExecutor",
                            ["backend", "1 worker rollouts/s", "2 workers rollouts/s", "speed-up"],
                            throughput(a.n_throughput, g)))
    if "memory" in a.only:
        tables.append(table(f"Memory over {a.n_memory} consecutive rollouts (lift 5x5, 0.2 s each, one instance)",
                            ["backend", "RSS after 10 (MB)", "RSS after all (MB)", "growth (MB)"],
                            memory(a.n_memory, 5)))
    return {"tables": tables}


def speed(grids, repeats):
    rows = []
    for b, cls in BACKENDS.items():
        for name in SCENARIOS:
            sc = make_scenario(name)
            rope = name == "winding"
            for g in grids:
                sim = cls(grid=g, rope_nodes=2 * g + 2)
                th = sim.param_space(sc).midpoint()
                sim.simulate(sc, th)
                ros = [sim.simulate(sc, th) for _ in range(repeats)]
                walls, r = [ro.info["wall_s"] for ro in ros], ros[-1]
                mesh = f"rope {2 * g + 2}" if rope else f"{g}x{g}"
                rows.append([b, name, mesh, r.vertices.shape[1], round(statistics.median(walls) / sc.duration, 3)])
    return rows


def raw_mujoco(sim, sc, th):
    import mujoco
    spec = sim.build_spec(sc, th)
    t0 = time.perf_counter()
    m = mujoco.MjModel.from_xml_string(spec_to_xml(spec))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    off = d.mocap_pos[0] - sc.gripper[0]
    tgt = sc.gripper + off
    dt = m.opt.timestep
    n = int(round(sc.times[-1] / dt))
    out = []
    fs = set(np.round(sc.times / dt).astype(int).tolist())
    for s in range(1, n + 1):
        d.mocap_pos[0] = [np.interp(s * dt, sc.times, tgt[:, c]) for c in range(3)]
        mujoco.mj_step(m, d)
        if s in fs:
            out.append(d.flexvert_xpos.copy())
    return time.perf_counter() - t0


def raw_pybullet(sim, sc, th):
    """The cloth scene of PybulletMassSpring.simulate (the same model helpers: vertices, spring constants, substeps,
    world), stepped by a plain pybullet loop: no parameter or plausibility checks, no effects, no Rollout."""
    import pybullet as p
    from softsbi.backends.common import grid_faces
    from softsbi.backends.pybullet_massspring.model import build_world, cloth_vertices, spring_constants, substeps
    from softsbi.backends.scenario_build import handle_targets, handle_vertices
    t0 = time.perf_counter()
    cid = sim._client()
    L, n, dt = th["scale"], sim.grid, sim.timestep
    v0 = cloth_vertices(sc, L, n, sc.table_z + sim.margin, th)
    mass = th["mass"] * L * L
    k_el, k_be = spring_constants(th["bend"], th["stretch"], L / (n - 1))
    sub = substeps(max(k_el, k_be), dt, mass / len(v0), sim.max_substeps)
    bodies, grips, starts = build_world(p, cid, sc, v0, grid_faces(n), rope=False, total_mass=mass,
                                        friction=th["friction"], k_el=k_el, k_be=k_be, k_da=sim.damping,
                                        margin=sim.margin, step=dt / sub,
                                        grasps=[[v] for v in handle_vertices(sc, v0, n)])
    tgt = handle_targets(sc, starts)[0]
    nsteps = int(round(sc.times[-1] / dt))
    fs = set(np.round(sc.times / dt).astype(int).tolist())
    for s in range(1, nsteps + 1):
        p.resetBasePositionAndOrientation(grips[0], [float(np.interp(s * dt, sc.times, tgt[:, c])) for c in range(3)],
                                          [0, 0, 0, 1], physicsClientId=cid)
        for _ in range(sub):
            p.stepSimulation(physicsClientId=cid)
        if s in fs:
            p.getMeshData(bodies["soft"], -1, flags=p.MESH_DATA_SIMULATION_MESH, physicsClientId=cid)
    return time.perf_counter() - t0


def overhead(grid, repeats):
    rows = []
    sc = make_scenario("lift")
    for b, raw in (("mujoco-flex", raw_mujoco), ("pybullet-massspring", raw_pybullet)):
        sim = BACKENDS[b](grid=grid)
        th = sim.param_space(sc).midpoint()
        sim.simulate(sc, th)
        a, r = [], []
        for _ in range(repeats):  # interleaved so machine load affects both alike
            t0 = time.perf_counter()
            sim.simulate(sc, th)
            a.append(time.perf_counter() - t0)
            r.append(raw(sim, sc, th))
        ma, mr = statistics.median(a), statistics.median(r)
        rows.append([b, round(ma, 3), round(mr, 3), round(100 * (ma / mr - 1), 1)])
    return rows


def _job(ctx, item):
    b, grid, sc, th = ctx
    return BACKENDS[b](grid=grid).simulate(sc, th).status


def throughput(n, grid):
    rows = []
    sc = make_scenario("lift")
    for b, cls in BACKENDS.items():
        th = cls(grid=grid).param_space(sc).midpoint()
        rates = []
        for w in (1, 2):
            ex = LocalExecutor(workers=w)
            ctx = (b, grid, sc, th)
            if w > 1:  # warm the pool (spawn + imports) outside the timing
                list(ex.map_unordered(_job, [0] * w, context=ctx))
            t0 = time.perf_counter()
            res = [r for _, r in ex.map_unordered(_job, list(range(n)), context=ctx)]
            rates.append(n / (time.perf_counter() - t0))
            ex.close()
            assert all(r == 0 for r in res), res
        rows.append([b, round(rates[0], 2), round(rates[1], 2), round(rates[1] / rates[0], 2)])
    return rows


def memory(n, grid):
    rows = []
    sc = make_scenario("lift", n_frames=5, frame_dt=0.05)  # short rollouts: 0.2 s each
    for b, cls in BACKENDS.items():
        sim = cls(grid=grid)
        th = sim.param_space(sc).midpoint()
        rss = []
        for i in range(n):
            sim.simulate(sc, th)
            if i in (9, n - 1):
                gc.collect()
                with open("/proc/self/status") as fh:
                    rss.append(int(next(line for line in fh if line.startswith("VmRSS")).split()[1]) / 1024)
        rows.append([b, round(rss[0], 1), round(rss[1], 1), round(rss[1] - rss[0], 1)])
    return rows
