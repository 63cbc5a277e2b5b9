"""What one DQN gradient step costs on this CPU: ours against a plain PyTorch reference of the same shapes.

    OMP_NUM_THREADS=1 .venv/bin/python scripts/update_floor.py            # about 30 s
    OMP_NUM_THREADS=2 .venv/bin/python scripts/update_floor.py --threads 2

Algorithm 1 takes one gradient step per environment step, so a paper run (Table 2: 5e5 environment steps)
is 5e5 steps on a batch of n_b = 256 through the §4.1 network (37 -> 256 -> 256 -> out). The reference is
the textbook form (torch.nn.Linear layers, autograd, gradient clipping, fused Adam, a target network
forward for the TD target), not something we could ship for 11 experts with their own moments and
counters: it bounds from below what any code of ours can reach per step on this machine. The figure
printed as `paper_run_updates_min` is the time of those 5e5 gradient steps alone (no simulation, no rule
layer), that is the floor of a paper run on the CPU at Algorithm 1's rate.

Prints one JSON object: milliseconds per gradient step (median of --repeats timings of --steps steps each)
for `ours` (DQNLearner.update, one member, the compact trainer's path; `ours_masked`, the static form's
update_masked) and `reference`, and each projected to 5e5 steps in minutes.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from highway_srl.agents.dqn import DQNConfig, DQNLearner
from highway_srl.constants import BATCH_SIZE, OBS_DIM, TOTAL_STEPS

OUT_DIM = 4  # A* (the mapped methods' four actions)


def reference_step(hidden: int):
    """A plain DQN gradient step of the same shapes: nn.Linear layers, autograd, clipping, fused Adam."""

    def mlp():
        return torch.nn.Sequential(torch.nn.Linear(OBS_DIM, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, hidden),
                                   torch.nn.ReLU(), torch.nn.Linear(hidden, OUT_DIM))

    online, target = mlp(), mlp()
    target.load_state_dict(online.state_dict())
    adam = torch.optim.Adam(online.parameters(), lr=DQNConfig.lr, fused=True)
    obs, nxt, reward = torch.randn(BATCH_SIZE, OBS_DIM), torch.randn(BATCH_SIZE, OBS_DIM), torch.randn(BATCH_SIZE)
    action = torch.randint(0, OUT_DIM, (BATCH_SIZE,))

    def step():
        with torch.no_grad():
            y = reward + DQNConfig.gamma * target(nxt).amax(1)
        q = online(obs).gather(1, action.unsqueeze(1)).squeeze(1)
        loss = (q - y).square().mean()
        adam.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(online.parameters(), DQNConfig.grad_clip_norm, foreach=True)
        adam.step()

    return step


def our_steps():
    """DQNLearner's update (compact) and update_masked (static) of one member of an 11-expert stack."""
    learner = DQNLearner(11, torch.ones(11, OUT_DIM, dtype=torch.bool), DQNConfig(), "cpu", OBS_DIM, OUT_DIM,
                         generator=torch.Generator().manual_seed(0))
    batch = {"obs": torch.randn(1, BATCH_SIZE, OBS_DIM), "next_obs": torch.randn(1, BATCH_SIZE, OBS_DIM),
             "action": torch.randint(0, OUT_DIM, (1, BATCH_SIZE)), "reward": torch.randn(1, BATCH_SIZE),
             "done": torch.zeros(1, BATCH_SIZE, dtype=torch.bool)}
    member, mask = torch.zeros(1, dtype=torch.long), torch.ones(1, dtype=torch.bool)
    return (lambda: learner.update(member, batch)), (lambda: learner.update_masked(member, batch, mask))


def time_ms(step, steps: int, repeats: int) -> float:
    for _ in range(20):  # warm caches and the allocator
        step()
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            step()
        runs.append((time.perf_counter() - start) / steps * 1e3)
    return statistics.median(runs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--steps", type=int, default=200, help="gradient steps per timing")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    ours, ours_masked = our_steps()
    forms = {"ours": ours, "ours_masked": ours_masked, "reference": reference_step(DQNConfig.hidden)}
    ms = {name: round(time_ms(step, args.steps, args.repeats), 3) for name, step in forms.items()}
    print(json.dumps({
        "threads": torch.get_num_threads(), "batch": BATCH_SIZE, "hidden": DQNConfig.hidden, "ms_per_step": ms,
        "paper_run_updates_min": {name: round(v * TOTAL_STEPS / 1e3 / 60, 1) for name, v in ms.items()},
        "torch": torch.__version__,
    }))


if __name__ == "__main__":
    main()
