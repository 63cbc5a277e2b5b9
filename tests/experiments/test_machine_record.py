"""Benchmark and study records say which of torch's CPU kernels ran (they move the figures and the last bits)."""

import platform

import torch

from highway_srl.experiments.bench import bench_sim
from highway_srl.study.runner import machine


def test_bench_and_study_records_name_the_cpu_kernels():
    record = bench_sim("two-lane", "C", envs=2, steps=2, device="cpu")["machine"]
    assert record["cpu_kernels"] == torch.backends.cpu.get_cpu_capability() == machine()["cpu_kernels"]
    if platform.machine().lower() in ("x86_64", "amd64"):
        assert record["cpu_kernels"] == "AVX2"  # the suite's setting (tests/conftest.py), whatever the host has
