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

# tiers, by markers on the tests themselves: a module that fits, simulates a real engine, runs the CLI or starts
# processes declares ``pytestmark = pytest.mark.integration``; every other test is the unit tier (toy simulator
# and hand-built results, arrays in and out). Tests marked ``slow`` (the demo, real recordings, fault injection,
# statistical checks) are left to whoever changes those paths: ``pytest -m slow``; the unit tier is
# ``-m unit`` (the marker is added below to every test that is neither integration nor slow), the integration tier
# ``-m "integration and not slow"``.


def pytest_collection_modifyitems(config, items):
    """Mark the unit tier: every test that is neither ``integration`` nor ``slow`` (``pytest -m unit``)."""
    for item in items:
        if item.get_closest_marker("integration") is None and item.get_closest_marker("slow") is None:
            item.add_marker(pytest.mark.unit)

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
