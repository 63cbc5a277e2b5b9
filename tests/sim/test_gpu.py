"""The same seeds on CUDA and on the CPU give the same episodes (up to float rounding)."""

from __future__ import annotations

from dataclasses import fields

import pytest
import torch

from highway_srl.sim import World, rng
from highway_srl.sim.ego_driver import idm_ego

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device; none is available here"),
]


def test_random_draws_are_identical_on_cuda_and_cpu():
    seed = torch.arange(1000, dtype=torch.long) * 7919 + 3
    episode = torch.arange(1000, dtype=torch.long) % 5
    k_cpu = rng.key(seed, episode, 17, 4)
    k_gpu = rng.key(seed.cuda(), episode.cuda(), 17, 4)
    assert torch.equal(k_cpu, k_gpu.cpu())
    assert torch.equal(rng.uniform(k_cpu, 9), rng.uniform(k_gpu, 9).cpu())


@pytest.mark.parametrize("scenario", ["two-lane", "multi-lane", "merge", "exit"])
def test_cuda_and_cpu_worlds_agree_step_by_step(scenario):
    seeds = list(range(40, 72))
    cpu = World(scenario, "C", adversarial=True, num_envs=len(seeds), seed=seeds, device="cpu")
    gpu = World(scenario, "C", adversarial=True, num_envs=len(seeds), seed=seeds, device="cuda")
    for f in fields(cpu.state):  # spawning: integer hashing and sums, identical up to rounding
        a, b = getattr(cpu.state, f.name), getattr(gpu.state, f.name).cpu()
        assert torch.allclose(a.double(), b.double(), atol=1e-4), f.name
    for t in range(40):
        # drive both with the CPU's commands so that a rounding difference cannot change the driver's choice
        lane, speed = idm_ego(cpu)
        e_cpu = cpu.step(lane, speed)
        e_gpu = gpu.step(lane.cuda(), speed.cuda())
        for name in ("x", "y", "v", "heading"):
            a, b = getattr(cpu.state, name), getattr(gpu.state, name).cpu()
            assert torch.allclose(a, b, atol=1e-3), (t, name, float((a - b).abs().max()))
        for name in ("lane", "target_lane", "forced"):
            assert torch.equal(getattr(cpu.state, name), getattr(gpu.state, name).cpu()), (t, name)
        assert torch.equal(e_cpu.collision, e_gpu.collision.cpu())
        assert torch.equal(e_cpu.sv_collisions, e_gpu.sv_collisions.cpu())
