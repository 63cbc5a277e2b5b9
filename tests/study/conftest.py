import sys
from pathlib import Path

import pytest

# study_fakes (synthetic job results) must be importable by name, also in spawned worker processes
sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    """One thread for every study test (tests/conftest.py)."""
