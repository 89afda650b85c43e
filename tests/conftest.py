import os
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
