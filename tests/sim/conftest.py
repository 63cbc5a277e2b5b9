"""Shared set-up of the simulator tests.

- Lets them import their helpers (sim_helpers.py) whatever pytest's import mode.
- Runs each test with one intra-op thread (the `one_thread` fixture of tests/conftest.py): their tensors are
  small, so threads only add overhead, and on a busy machine OpenMP's spinning workers make small ops 10-50x
  slower.
"""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    """One thread for every simulator test (tests/conftest.py)."""
