import sys
from pathlib import Path

import pytest
import torch

# study_fakes (synthetic job results) must be importable by name, also in spawned worker processes
sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)
    yield
