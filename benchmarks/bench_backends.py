"""Backend benchmarks (issue 3): speed per backend x scenario x mesh size, softsbi overhead over a
raw engine loop, 2-worker throughput and memory over many rollouts.

Usage::

    python benchmarks/bench_backends.py [--grids 7 11] [--repeats 3] [--n-throughput 16] [--n-memory 500]

Prints markdown tables (paste into BENCHMARKS.md). Single-threaded engines; the machine is
shared, so every figure is the median of ``--repeats`` runs.
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

BACKENDS = {"mujoco-flex": MujocoFlex, "pybullet-massspring": PybulletMassSpring}


def speed(grids, repeats):
    print("\n### Wall time per simulated second (s), prior midpoint, median of", repeats)
    print("| backend | scenario | mesh | vertices | wall s / sim s |\n|---|---|---|---|---|")
    for b, cls in BACKENDS.items():
        for name in SCENARIOS:
            sc = make_scenario(name)
            rope = name == "winding"
            for g in grids:
                sim = cls(grid=g, rope_nodes=2 * g + 2) if True else None
                th = sim.param_space(sc).midpoint()
                sim.simulate(sc, th)
                walls = [sim.simulate(sc, th).info["wall_s"] for _ in range(repeats)]
                r = sim.simulate(sc, th)
                mesh = f"rope {2 * g + 2}" if rope else f"{g}x{g}"
                print(f"| {b} | {name} | {mesh} | {r.vertices.shape[1]} | "
                      f"{statistics.median(walls) / sc.duration:.3f} |", flush=True)


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
    """The same scene as PybulletMassSpring.simulate, written as a plain pybullet loop (no softsbi checks)."""
    import os
    import tempfile
    import pybullet as p
    from softsbi.backends.common import grid_faces
    from softsbi.backends.pybullet_massspring import cloth_vertices, write_obj
    t0 = time.perf_counter()
    cid = sim._client()
    L = th["scale"]
    n = sim.grid
    v0 = cloth_vertices(sc, L, n, sc.table_z + sim.margin)
    mass = th["mass"] * L * L
    sub = sim.simulate.__self__ and 1
    m_node = mass / len(v0)
    import math
    sub = min(sim.max_substeps, max(1, math.ceil(math.sqrt(max(th["stretch"], th["bend"]) * sim.timestep ** 2
                                                            / (1.5 * m_node)))))
    p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD, physicsClientId=cid)
    p.setGravity(0, 0, -9.81, physicsClientId=cid)
    p.setTimeStep(sim.timestep / sub, physicsClientId=cid)
    box = p.createCollisionShape(p.GEOM_BOX, halfExtents=[3, 3, 0.05], physicsClientId=cid)
    p.createMultiBody(0, box, basePosition=[0, 0, sc.table_z - 0.05], physicsClientId=cid)
    fd, path = tempfile.mkstemp(suffix=".obj")
    os.close(fd)
    write_obj(path, v0, grid_faces(n))
    sb = p.loadSoftBody(path, mass=mass, useNeoHookean=0, useMassSpring=1, useBendingSprings=1,
                        springElasticStiffness=th["stretch"], springBendingStiffness=th["bend"],
                        springDampingStiffness=sim.damping, springDampingAllDirections=1, frictionCoeff=th["friction"],
                        useFaceContact=1, collisionMargin=sim.margin, physicsClientId=cid)
    os.unlink(path)
    g = p.createMultiBody(0, -1, basePosition=v0[0].tolist(), physicsClientId=cid)
    p.createSoftBodyAnchor(sb, 0, g, -1, physicsClientId=cid)
    tgt = sc.gripper + (v0[0] - sc.gripper[0])
    dt = sim.timestep
    nsteps = int(round(sc.times[-1] / dt))
    fs = set(np.round(sc.times / dt).astype(int).tolist())
    for s in range(1, nsteps + 1):
        p.resetBasePositionAndOrientation(g, [float(np.interp(s * dt, sc.times, tgt[:, c])) for c in range(3)],
                                          [0, 0, 0, 1], physicsClientId=cid)
        for _ in range(sub):
            p.stepSimulation(physicsClientId=cid)
        if s in fs:
            p.getMeshData(sb, -1, flags=p.MESH_DATA_SIMULATION_MESH, physicsClientId=cid)
    return time.perf_counter() - t0


def overhead(grid, repeats):
    print(f"\n### softsbi rollout vs a raw engine loop (lift, {grid}x{grid}), median of {repeats}")
    print("| backend | softsbi s | raw s | overhead |\n|---|---|---|---|")
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
        print(f"| {b} | {ma:.3f} | {mr:.3f} | {100 * (ma / mr - 1):+.1f}% |", flush=True)


def _job(ctx, item):
    b, grid, sc, th = ctx
    return BACKENDS[b](grid=grid).simulate(sc, th).status


def throughput(n, grid):
    print(f"\n### Throughput, {n} lift rollouts ({grid}x{grid}), LocalExecutor")
    print("| backend | 1 worker rollouts/s | 2 workers rollouts/s | speed-up |\n|---|---|---|---|")
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
        print(f"| {b} | {rates[0]:.2f} | {rates[1]:.2f} | {rates[1] / rates[0]:.2f}x |", flush=True)


def memory(n, grid):
    print(f"\n### Memory over {n} consecutive rollouts (lift, {grid}x{grid}, one instance)")
    print("| backend | RSS after 10 (MB) | RSS after all (MB) | growth (MB) |\n|---|---|---|---|")
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
                    rss.append(int(next(l for l in fh if l.startswith("VmRSS")).split()[1]) / 1024)
        print(f"| {b} | {rss[0]:.1f} | {rss[1]:.1f} | {rss[1] - rss[0]:+.1f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grids", type=int, nargs=2, default=[7, 11])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--n-throughput", type=int, default=16)
    ap.add_argument("--n-memory", type=int, default=500)
    ap.add_argument("--only", nargs="*", default=["speed", "overhead", "throughput", "memory"])
    a = ap.parse_args()
    with open("/proc/loadavg") as fh:
        print(f"load average at start: {fh.read().split()[:3]}")
    if "speed" in a.only:
        speed(a.grids, a.repeats)
    if "overhead" in a.only:
        overhead(a.grids[0], max(a.repeats, 5))
    if "throughput" in a.only:
        throughput(a.n_throughput, a.grids[0])
    if "memory" in a.only:
        memory(a.n_memory, 5)
    with open("/proc/loadavg") as fh:
        print(f"\nload average at end: {fh.read().split()[:3]}")


if __name__ == "__main__":
    main()
