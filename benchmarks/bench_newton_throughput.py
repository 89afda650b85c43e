"""The newton-throughput suite: lift rollouts per second on newton-cloth, one by one and batched, against
mujoco-flex in the same run.

For each N (``--n``), N parameter sets are drawn from the lift's prior (seeded). mujoco-flex and newton-cloth
roll them out one by one (``simulate``; timed on the first ``--single-max`` of them, as the rate does not depend
on N), and newton-cloth rolls all N out as one batch (``simulate_batch``: N worlds in one Newton model). The
first newton-cloth rollout of the run is a warm-up, not timed: it compiles Warp's kernels on a machine that
has not yet (``compile_s``; cached afterwards). ``--device cuda`` runs newton-cloth on the GPU (mujoco-flex
always runs on one CPU core).

Needs the optional Newton package; without it the suite stops in one line naming ``pip install
"softsbi[newton]"``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.runner import table


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--device", default="cpu", help="Warp device of newton-cloth: cpu or cuda (cuda:0, ...)")
    ap.add_argument("--n", type=int, nargs="+", default=[1, 8], help="batch sizes N")
    ap.add_argument("--single-max", type=int, default=4,
                    help="rollouts timed one by one per engine (the sequential rate does not depend on N)")
    ap.add_argument("--grid", type=int, default=9, help="cloth vertices per side (both engines)")
    ap.add_argument("--seed", type=int, default=0)


FULL = {"n": [1, 8, 64]}


def config(a: argparse.Namespace) -> str:
    """The stored configuration of a run: ``full`` or ``default``, on the device (``default-cuda``)."""
    base = "full" if getattr(a, "full", False) else "default"
    return base if a.device == "cpu" else f"{base}-{a.device.replace(':', '')}"


def _check_device(device: str) -> str:
    """Newton's import and the device, checked before any work; returns the device's name.

    Raises:
        SystemExit: Newton or MuJoCo is missing, or the device does not exist (one line naming the fix).
    """
    from softsbi.backends.mujoco_flex.gl import import_mujoco
    from softsbi.backends.newton_cloth import import_newton
    from softsbi.core.errors import DependencyMissing, EnvironmentFault
    try:
        import_mujoco()  # the baseline of the same run
        _, wp = import_newton()
    except (DependencyMissing, EnvironmentFault) as exc:
        raise SystemExit(str(exc)) from None
    try:
        dev = wp.get_device(device)
    except Exception as exc:  # noqa: BLE001 - Warp raises plain errors for unknown devices
        raise SystemExit(f"--device {device}: Warp has no such device ({exc}); Warp sees: "
                         f"{', '.join(str(d) for d in wp.get_devices())}") from None
    return getattr(dev, "name", str(dev))


def _rate(n_ok: int, seconds: float) -> float | None:
    return None if seconds <= 0 else round(n_ok / seconds, 3)


def suite(a: argparse.Namespace) -> dict:
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.backends.newton_cloth import NewtonCloth
    from softsbi.scenarios.builtin import make_scenario

    card = _check_device(a.device)
    sc = make_scenario("lift")
    nw = NewtonCloth(grid=a.grid, device=a.device)
    mj = MujocoFlex(grid=a.grid)
    space = nw.param_space(sc)
    rng = np.random.default_rng(a.seed)
    t0 = time.perf_counter()
    nw.simulate(sc, space.midpoint())  # warm-up: compiles Warp's kernels where not cached
    compile_s = round(time.perf_counter() - t0, 1)
    rows, data = [], []
    for n in a.n:
        thetas = [dict(zip(space.names, row)) for row in space.sample_prior(n, rng)]
        single = thetas[:a.single_max]
        res = {"n": n}
        for name, sim in (("mujoco-flex", mj), ("newton-cloth", nw)):
            t = time.perf_counter()
            ok = sum(sim.simulate(sc, th).ok for th in single)
            res[f"{name}_single_per_s"] = _rate(len(single), time.perf_counter() - t)
            res[f"{name}_single_ok"] = f"{ok}/{len(single)}"
        t = time.perf_counter()
        batch = nw.simulate_batch(sc, thetas)
        res["newton-cloth_batch_per_s"] = _rate(n, time.perf_counter() - t)
        res["newton-cloth_batch_ok"] = f"{sum(r.ok for r in batch)}/{n}"
        data.append(res)
        rows.append([n, res["mujoco-flex_single_per_s"], res["newton-cloth_single_per_s"],
                     res["newton-cloth_batch_per_s"], res["newton-cloth_batch_ok"]])
    note = (f"lift ({sc.times[-1]:.2f} s simulated), grid {a.grid}; newton-cloth VBD {nw.iterations} iterations at "
            f"{1000 * nw.timestep:g} ms on {a.device} ({card}); mujoco-flex on one CPU core. One-by-one rates timed on "
            f"min(N, {a.single_max}) rollouts. Kernel compile / warm-up of the run: {compile_s} s.")
    return {"tables": [table(f"Lift rollouts per second, newton-cloth on {a.device} ({card})",
                             ["N", "mujoco-flex one by one", "newton-cloth one by one", "newton-cloth batch of N",
                              "batch rollouts ok"], rows, note=note)],
            "data": {"rows": data, "compile_s": compile_s, "device": a.device, "card": card}}
