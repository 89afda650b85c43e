import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

#: ../shared/data beside the repository (never copied into the project)
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
LIFT = DATA / "diffcloud_lift"


@pytest.fixture
def lift_dir() -> Path:
    if not (LIFT / "lift_tan").is_dir():
        pytest.skip(f"real data not found at {LIFT} (expected ../shared/data beside the repository)")
    return LIFT


os.environ.setdefault("OMP_NUM_THREADS", "2")

#: test modules that fit, simulate a real engine, run the CLI or start processes: the integration tier (marker
#: ``integration``); every other test is the unit tier (toy simulator and hand-built results, arrays in and out).
#: Tests marked ``slow`` (the demo, real recordings, fault injection, statistical checks) are left to whoever
#: changes those paths: ``pytest -m slow``.
INTEGRATION = {
    "test_aniso_plugin.py", "test_backend_units.py", "test_bank.py", "test_bestfit_widen.py", "test_calibrate.py",
    "test_check_camera.py", "test_cli_inputs.py", "test_cli_recording.py", "test_compare_backends.py",
    "test_conformance.py", "test_demo.py", "test_depth_sensor.py", "test_diagnose_toy.py", "test_diagnostics.py",
    "test_executors.py", "test_faults.py", "test_flow_fit.py", "test_image_fit.py", "test_mujoco_flex.py",
    "test_no_gl.py", "test_output_folders.py", "test_pybullet_massspring.py", "test_readme.py", "test_registry.py",
    "test_render.py", "test_run_safety.py", "test_runs.py", "test_scenarios_all.py", "test_sensor_draws.py",
    "test_sensor_metric.py", "test_store_loop.py", "test_tutorial.py", "test_view.py", "test_heatmap.py",
    "test_transporter.py", "test_occlusion.py", "test_bound_pressure.py", "test_builtin_regression.py",
    "test_door.py", "test_files.py", "test_stored_results.py", "test_newton_cloth.py",
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in INTEGRATION and "slow" not in item.keywords:
            item.add_marker(pytest.mark.integration)
# no simulation bank unless a test asks for one: a bank shared by tests would hand one test's stored rollouts to
# another that injects faults into the simulator (tests/workflows/test_bank.py switches it on where it is tested);
# set, not defaulted, so that a user's own bank in the environment cannot reach the tests either
os.environ["SOFTSBI_SIM_BANK"] = "off"


def _kill_when_stored(script: str, out: Path, n: int, env: dict | None = None, timeout: float = 120) -> int:
    """Run ``script`` (a fit writing ``out/run.zarr``) in a driver process and SIGKILL it once at
    least ``n`` simulations of round 0 are stored; returns how many were stored."""
    import zarr
    from softsbi.core.types import STATUS_PENDING
    proc = subprocess.Popen([sys.executable, "-c", script], env=env)
    deadline = time.time() + timeout
    done = 0
    while time.time() < deadline and proc.poll() is None:
        time.sleep(0.3)
        try:
            st = zarr.open_group(str(out / "run.zarr"), mode="r")["rounds"]["0"]["status"][...]
            done = int((st != STATUS_PENDING).sum())
        except Exception:  # noqa: BLE001 - the store is still being created
            continue
        if done >= n:
            break
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return done


@pytest.fixture
def kill_when_stored():
    """``kill_when_stored(script, out, n, env=None) -> stored``: kill a fit's driver mid-round."""
    return _kill_when_stored
