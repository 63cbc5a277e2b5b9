"""Fixtures shared by every test folder."""

import os
import platform

# The pins (tests/pins) are bit-exact hashes, and torch's vectorised CPU kernels round differently on
# different instruction sets (AVX2 and AVX-512 sum and evaluate exp/log in other orders): the same code gives
# other last bits on an AVX-512 machine. The suite runs torch's AVX2 kernels on every x86 machine, the set the
# pins were recorded with (tests/pins/pin_data.py does the same). torch reads the setting once, at its first
# CPU kernel, so it is set here, before any test runs one; an explicit setting of the user's is kept.
PINNED_CPU_CAPABILITY = "avx2"
if platform.machine().lower() in ("x86_64", "amd64"):
    os.environ.setdefault("ATEN_CPU_CAPABILITY", PINNED_CPU_CAPABILITY)

import pytest  # noqa: E402
import torch  # noqa: E402


def pytest_configure(config):
    """Under pytest-xdist (`make test`: one worker per core) each worker takes its share of the cores for
    torch's intra-op threads, so that the workers do not fight over them."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
    if workers > 1:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        torch.set_num_threads(max(1, cores // workers))


@pytest.fixture
def one_thread():
    """The test runs with one intra-op thread; the previous setting is restored afterwards.

    Used where it matters (autouse in tests/sim, tests/agents, tests/pins, tests/study and
    tests/cli/test_methods_cli.py): their tensors and networks are small, so a second thread only adds
    OpenMP waits, and on a machine whose cores are busy with other work a barrier waiting for a descheduled
    thread makes small ops 10-50x slower.
    The pins also need it for their numbers (see tests/pins/conftest.py).
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
