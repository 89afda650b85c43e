"""A fresh machine: no OpenGL library at all, a bogus MUJOCO_GL, an engine that cannot load.

Simulation, fits and the demo never load OpenGL; rendering chooses its back-end when asked and
fails with one line naming the fix; an environment fault stops a fit without storing anything as
failed, and the same call resumes once the environment is fixed. The environment is broken in
subprocesses through ``tests/fault_env/sitecustomize.py`` (ctypes refuses every GL library;
optionally ``import mujoco`` fails).
"""
import json
import os
import pickle
import subprocess
import sys

import numpy as np
import pytest
from toy_helpers import FAULT_ENV

pytestmark = pytest.mark.integration


def _env(block: str = "gl", mujoco_gl: str | None = "osmesa") -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(FAULT_ENV)] + [p for p in [env.get("PYTHONPATH")] if p])
    env["SOFTSBI_TEST_BLOCK"] = block
    env.pop("MUJOCO_GL", None)
    if mujoco_gl is not None:
        env["MUJOCO_GL"] = mujoco_gl
    return env


def _softsbi(args: list[str], env: dict, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "softsbi.cli", *args], env=env, capture_output=True, text=True,
                          timeout=timeout)


def test_the_blocker_really_blocks_gl():
    code = ("import ctypes, ctypes.util\n"
            "assert ctypes.util.find_library('OSMesa') is None and ctypes.util.find_library('EGL') is None\n"
            "try:\n    ctypes.CDLL('libEGL.so.1')\nexcept OSError:\n    print('blocked')\n")
    r = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=60)
    assert r.stdout.strip() == "blocked", r.stderr


def test_simulation_loads_no_opengl_even_with_mujoco_gl_osmesa_and_no_library():
    code = ("import sys\n"
            "from softsbi.scenarios.builtin import lift_scenario\n"
            "from softsbi.plugins import registry\n"
            "sc = lift_scenario(None)\n"
            "sim = registry().simulator('mujoco-flex')(grid=5)\n"
            "ro = sim.simulate(sc, sim.param_space(sc).midpoint())\n"
            "maps = open('/proc/self/maps').read()\n"
            "gl = [m for m in sys.modules if m.startswith('OpenGL') or m in ('mujoco.osmesa', 'mujoco.egl')]\n"
            "libs = sorted({l.split('/')[-1] for l in maps.splitlines() if 'libGL' in l or 'OSMesa' in l "
            "or 'libEGL' in l})\n"
            "print(ro.ok, gl, libs)\n")
    r = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "True [] []", r.stdout


@pytest.mark.parametrize("mujoco_gl, expected", [
    (None, "apt-get install -y libosmesa6"),
    pytest.param("osmesa", "apt-get install -y libosmesa6", marks=pytest.mark.slow),
    pytest.param("bogus", "MUJOCO_GL='bogus'", marks=pytest.mark.slow)])
def test_a_render_request_without_gl_is_one_clear_line(tmp_path, mujoco_gl, expected):
    r = _softsbi(["simulate", "--backend-opt", "grid=5", "--render", "32", "--out", str(tmp_path / "r")],
                 _env(mujoco_gl=mujoco_gl), timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and "pybullet build time" not in ln]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert expected in lines[0] and "Traceback" not in r.stderr
    # the same under --json: one JSON error document on stdout
    r = _softsbi(["simulate", "--backend-opt", "grid=5", "--render", "32", "--out", str(tmp_path / "r"), "--json"],
                 _env(mujoco_gl=mujoco_gl), timeout=120)
    assert r.returncode == 2
    doc = json.loads(r.stdout)
    assert doc["type"] == "RenderingUnavailable" and expected in doc["error"]


def test_bogus_mujoco_gl_does_not_stop_simulation(tmp_path):
    r = _softsbi(["simulate", "--backend-opt", "grid=5", "--out", str(tmp_path / "s"), "--json"],
                 _env(mujoco_gl="bogus"), timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["status"] == 0


@pytest.mark.slow
def test_demo_quick_runs_with_every_gl_library_blocked(tmp_path):
    """README command 1's job on a machine without any OpenGL (a small budget; the full demo is
    timed in the closing note and run by CI through the README)."""
    r = _softsbi(["demo", "--quick", "--rounds", "1", "--sims-per-round", "20", "--workers", "2",
                  "--out", str(tmp_path / "demo"), "--json"], _env(), timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    doc = json.loads(r.stdout)
    assert doc["quick"] and doc["parameters"] == 5
    assert doc["nominal"]["failed_simulations"] == 0
    assert (tmp_path / "demo" / "nominal" / "report.json").exists()


@pytest.mark.slow
def test_an_environment_fault_stores_nothing_as_failed_and_the_fit_resumes(tmp_path):
    from softsbi.scenarios.builtin import lift_scenario
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.core.store import RunStore
    from softsbi.core.types import STATUS_OK, STATUS_PENDING
    from softsbi.workflows.measurement import simulate_recording

    sc = lift_scenario(None)
    truth = {"bend": 1e-4, "stretch": 100.0, "friction": 0.5, "scale": 0.25, "mass": 0.25}
    meas = simulate_recording("mujoco-flex", sc, truth, backend_options={"grid": 5})
    cfg = FitConfig(rounds=1, sims_per_round=10, n_eval=5, workers=2, backend_options={"grid": 5},
                    min_height=0.01)
    (tmp_path / "meas.pkl").write_bytes(pickle.dumps((meas, cfg)))
    out = tmp_path / "run"
    code = ("import pickle, sys\n"
            "from softsbi.workflows.fit.run import run_fit\n"
            "from softsbi.core.errors import EnvironmentFault\n"
            f"meas, cfg = pickle.loads(open({str(tmp_path / 'meas.pkl')!r}, 'rb').read())\n"
            "try:\n"
            f"    run_fit({str(out)!r}, meas, cfg, make_plots=False)\n"
            "except EnvironmentFault as exc:\n"
            "    print('FAULT', exc)\n    sys.exit(3)\n")
    r = subprocess.run([sys.executable, "-c", code], env=_env(block="mujoco"), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 3, (r.stdout, r.stderr[-2000:])
    assert "pip install --force-reinstall mujoco" in r.stdout  # the fix
    status = RunStore.open(out / "run.zarr").round_data(0)["status"]
    assert np.all(status == STATUS_PENDING), status  # nothing stored as failed
    res = run_fit(out, meas, cfg, make_plots=False)  # the environment is fixed: the same call resumes
    assert res.report.failed_simulations == 0
    assert np.all(RunStore.open(out / "run.zarr").round_data(0)["status"] == STATUS_OK)
