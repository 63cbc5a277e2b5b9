"""The allocator setting a CPU world makes (sim/allocator.py): freed step memory is reused, not unmapped."""

from __future__ import annotations

import ctypes
import resource

import pytest
import torch

from highway_srl.sim import World, allocator


def _has_mallopt() -> bool:
    try:
        return hasattr(ctypes.CDLL(None), "mallopt")
    except (OSError, TypeError):
        return False


glibc = pytest.mark.skipif(not _has_mallopt(), reason="mallopt is glibc's")


def _churn() -> None:
    """Tensors of 1-8 MiB allocated and freed in an interleaved order, as a world step does."""
    for i in range(40):
        a = torch.ones(1 << (18 + i % 4))
        b = torch.ones(3 << 18)
        del a
        c = torch.ones(1 << 21)
        del b, c


@glibc
def test_a_cpu_world_makes_freed_tensor_memory_reused():
    World("two-lane", "C", num_envs=2)
    assert allocator.keep_freed_memory()  # set by the world, once for the process
    _churn()  # the heap grows to what the pattern needs
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    _churn()
    # the second pass reuses the first's memory; unmapped on free, each block's pages (40 passes x 12 MiB)
    # would fault in again
    assert resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before < 100


def test_the_setting_can_be_declined():
    assert allocator.tune_malloc({"HIGHWAY_SRL_DEFAULT_MALLOC": "1"}) is False


@glibc
def test_bench_figures_record_the_setting():
    from highway_srl.experiments.bench import bench_sim

    assert bench_sim("two-lane", "C", envs=2, steps=2, device="cpu")["machine"]["malloc"] == "tuned"
