"""Shared test helpers (importable from every test module: pytest puts ``tests/`` on ``sys.path``
through the root ``conftest.py``): paths and the toy plugin's recording."""
from pathlib import Path

#: this folder, the repository and ../shared/data beside it (never copied into the project)
TESTS_DIR = Path(__file__).resolve().parent
REPO = TESTS_DIR.parent
DATA = REPO.parent / "shared" / "data"
FAULT_ENV = TESTS_DIR / "fault_env"


def toy_measurement(truth=(0.3, -0.4), T=3, seed=5):
    """A recording of the toy-gauss simulator (tests/plugins/softsbi_toy) at ``truth`` = (a, b)."""
    from softsbi_toy import plugin as toy

    from softsbi.workflows.measurement import simulate_recording
    sc = toy.toy_scenario(T)
    return simulate_recording("toy-gauss", sc, {"a": truth[0], "b": truth[1]}, n_points=16, n_dense=64, seed=seed)


def copy_lift_recording(tmp_path, lift_dir=DATA / "diffcloud_lift"):
    """A writable copy of the real lift_tan recording in DiffCloud's layout (the parent folder holds
    ``lift_traj.npy`` and the default ``lift_real2sim.yaml``); returns the ``lift_tan`` folder."""
    import shutil
    dst = tmp_path / "diffcloud_lift"
    dst.mkdir()
    for f in ("lift_traj.npy", "lift_real2sim.yaml"):
        shutil.copy(lift_dir / f, dst / f)
    shutil.copytree(lift_dir / "lift_tan", dst / "lift_tan")
    return dst / "lift_tan"
