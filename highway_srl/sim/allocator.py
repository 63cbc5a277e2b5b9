"""Keep the memory of freed tensors in the process's heap instead of handing it back to the OS each step.

Why: at 4,096 envs one world step allocates and frees hundreds of tensors of 0.1-2 MB. glibc serves a
block above its mmap threshold (128 KiB at start, then adapted to the sizes it sees) with a fresh
mapping and unmaps it when freed, so every step faults its pages in again: 130,000-660,000 minor faults
in 250 steps of `bench sim --envs 4096`, up to a fifth of the time in the kernel, and how many a process
gets depends on how glibc's threshold happened to adapt (a 1.3x spread between runs of one command).
With the threshold at glibc's maximum (32 MiB) and the heap trimmed only when more than 1 GiB of it is
free, freed blocks are reused: about 48,000 faults, every run alike, and 1.2x the steps per second on
average (docs/benchmarks.md). The process keeps up to its peak tensor memory instead of
returning it between steps; peak memory itself does not grow.

Only glibc has mallopt (Linux); elsewhere, or with HIGHWAY_SRL_DEFAULT_MALLOC=1 in the environment,
nothing changes.
"""

from __future__ import annotations

import ctypes
import os

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20  # glibc's largest (HEAP_MAX_SIZE / 2 on 64-bit)
TRIM_THRESHOLD_BYTES = 1 << 30

_state = {"tuned": None}


def keep_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds for this process (once); True when they are set."""
    if _state["tuned"] is None:
        _state["tuned"] = tune_malloc(os.environ)
    return _state["tuned"]


def setting() -> str:
    """What this process runs with, for benchmark records: "tuned" (set by a CPU World), "default" (declined,
    not glibc, or no CPU World made yet)."""
    return "tuned" if _state["tuned"] else "default"


def tune_malloc(environ) -> bool:
    """Set the thresholds unless environ declines it; True when glibc took them."""
    if environ.get("HIGHWAY_SRL_DEFAULT_MALLOC", "") not in ("", "0"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError, TypeError):  # not glibc (TypeError: no CDLL(None) on Windows)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    # setting the mmap threshold also stops glibc from adapting it
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
