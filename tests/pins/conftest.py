import sys
from pathlib import Path

# pin_data is importable by name (the suite runs with --import-mode=importlib, no packages under tests/)
sys.path.insert(0, str(Path(__file__).parent))

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_thread():
    # the golden numbers were made with one thread (pin_data.py's __main__); with two, matmul reductions
    # split differently and the saved weights differ in the last bits (the behaviour does not)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
