import sys
from pathlib import Path

# pin_data is importable by name (the suite runs with --import-mode=importlib, no packages under tests/)
sys.path.insert(0, str(Path(__file__).parent))

import pytest


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    """One thread (tests/conftest.py): the golden numbers were made with one (pin_data.py's __main__); with
    two, matmul reductions split differently and the saved weights differ in the last bits (the behaviour
    does not)."""
