"""Benchmark and study records say which of torch's CPU kernels ran and MKL's reproducible mode (they move
the figures and the last bits)."""

import torch

from highway_srl.experiments.bench import bench_sim
from highway_srl.study.runner import machine


def test_bench_and_study_records_name_the_cpu_kernels_and_the_mkl_mode(monkeypatch):
    monkeypatch.setenv("MKL_CBWR", "COMPATIBLE")
    record = bench_sim("two-lane", "C", envs=2, steps=2, device="cpu")["machine"]
    assert record["cpu_kernels"] == torch.backends.cpu.get_cpu_capability() == machine()["cpu_kernels"] != ""
    assert record["mkl_cbwr"] == machine()["mkl_cbwr"] == "COMPATIBLE"
    monkeypatch.delenv("MKL_CBWR")
    assert bench_sim("two-lane", "C", envs=2, steps=2, device="cpu")["machine"]["mkl_cbwr"] == machine()["mkl_cbwr"] == ""
