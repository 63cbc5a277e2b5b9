"""Shared set-up of the simulator tests.

- Lets them import their helpers (sim_helpers.py) whatever pytest's import mode.
- Runs each test with one intra-op thread: their tensors are small, so threads only add overhead, and on
  a machine whose cores are busy with other work, OpenMP's spinning workers make small ops 10-50x slower.
  The previous setting is restored after each test.
"""

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(autouse=True)
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
