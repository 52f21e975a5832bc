import os
from pathlib import Path

import pytest

REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The real sensor captures in ../shared/data/real (never copied into the repo)."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real captures not found at {REAL_DATA}")
    return REAL_DATA


# Tests must not fight over the CPU with each other's thread pools on a 2-core machine.
os.environ.setdefault("OMP_NUM_THREADS", "2")
