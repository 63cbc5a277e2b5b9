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


@pytest.fixture(autouse=True)
def _pinned_kernels():
    """The pins hold for torch's AVX2 kernels (tests/conftest.py sets them): on another set the last bits
    differ, so say that instead of a hash mismatch that reads like a behaviour change."""
    import platform

    import torch

    if platform.machine().lower() in ("x86_64", "amd64"):
        capability = torch.backends.cpu.get_cpu_capability()
        if capability != "AVX2":
            pytest.fail(f"the pins need torch's AVX2 CPU kernels, this process runs {capability} "
                        "(ATEN_CPU_CAPABILITY was set to something else, or a kernel ran before tests/conftest.py)")
