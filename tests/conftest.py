"""Fixtures shared by every test folder."""

import os

import pytest
import torch


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
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(autouse=True)
def keep_omp_num_threads():
    """The CLI exports its thread count as OMP_NUM_THREADS (for its worker processes); a test that calls
    main() with --threads must not change the count that later tests see."""
    before = os.environ.get("OMP_NUM_THREADS")
    yield
    if before is None:
        os.environ.pop("OMP_NUM_THREADS", None)
    else:
        os.environ["OMP_NUM_THREADS"] = before
