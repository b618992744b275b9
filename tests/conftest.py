import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED_BVH = ROOT.parent / "shared" / "data" / "bvh"
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


@pytest.fixture(scope="session")
def shared_bvh() -> Path:
    if not SHARED_BVH.is_dir():
        pytest.skip("../shared/data/bvh is not present")
    return SHARED_BVH


def pytest_collection_modifyitems(config, items):
    """Ray-marked tests run last: Ray leaves native threads in the test process after shutdown,
    and a fork-based process pool started after them (the training-data generators) can
    deadlock in a child that inherited a held lock."""
    items.sort(key=lambda item: item.get_closest_marker("ray") is not None)
