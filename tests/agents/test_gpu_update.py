"""The DQN update on CUDA is the CPU's to float rounding: the compact form (gathered rows through torch's fused
Adam kernel, DQNLearner.update) and the static form (the elementwise step, update_masked). Run by
scripts/device_check.py; skipped without a CUDA device."""

from __future__ import annotations

import pytest
import torch

from highway_srl.agents.dqn import DQNConfig, DQNLearner
from highway_srl.agents.gating import expert_action_mask

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device; none is available here"),
]

# a target sync inside the run, gradients large enough to be clipped now and then
CONFIG = DQNConfig(hidden=64, batch_size=32, target_update_interval=3, grad_clip_norm=1.0)


def _batches(mask: torch.Tensor, steps: int) -> list[dict[str, torch.Tensor]]:
    gen = torch.Generator().manual_seed(11)
    k = mask.shape[0]
    return [{"obs": torch.randn(k, 32, 37, generator=gen), "next_obs": torch.randn(k, 32, 37, generator=gen),
             "action": torch.multinomial(mask.float(), 32, replacement=True, generator=gen),
             "reward": 5.0 * torch.randn(k, 32, generator=gen), "done": torch.rand(k, 32, generator=gen) < 0.2}
            for _ in range(steps)]


@pytest.mark.parametrize("masked", [False, True])
def test_cuda_update_follows_the_cpu_update(masked):
    members = torch.tensor([0, 4, 9])
    mask = expert_action_mask()
    learners = {dev: DQNLearner(11, mask, CONFIG, dev, generator=torch.Generator().manual_seed(2))
                for dev in ("cpu", "cuda")}
    for batch in _batches(mask[members], 8):
        for dev, learner in learners.items():
            on = {key: value.to(dev) for key, value in batch.items()}
            if masked:
                learner.update_masked(members.to(dev), on, torch.tensor([True, False, True], device=dev))
            else:
                learner.update(members.to(dev), on)
    cpu, cuda = learners["cpu"].state_dict(), learners["cuda"].state_dict()
    assert int(cpu["adam.step"][0]) == 8  # past target_update_interval: the target synced on both devices
    for key in cpu:
        torch.testing.assert_close(cuda[key].cpu(), cpu[key], rtol=1e-4, atol=1e-5, msg=key)
