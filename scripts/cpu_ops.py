"""Small CPU facts behind choices in sim/selection.py and agents/dqn.py, measured: what single operations cost,
and which operations' last bits depend on the machine's MKL.

    OMP_NUM_THREADS=1 python scripts/cpu_ops.py costs
    for e in X=1 MKL_ENABLE_INSTRUCTIONS=SSE4_2 MKL_ENABLE_INSTRUCTIONS=AVX2 MKL_CBWR=COMPATIBLE; do
        env $e python scripts/cpu_ops.py hashes; done

costs: microseconds per call (best of 5 timings) of `take_flat`'s two forms at growing index counts (why it
switches to torch.take below sim.selection.TAKE_MAX), and of the bookkeeping the gathered DQN update did per
member row of 76,548 floats (index_select, index_copy_, torch.where; why the CPU update works on rows), and
the two forms of ReLU's backward and of Adam on a row that the compact update chooses between.
hashes: an md5 prefix of each operation's output on 10^5 fixed floats; run it under different MKL settings
(as above) and compare: the operations whose hash moves take their last bits from MKL's code path, which MKL
picks by CPU model (why the pins run under MKL_CBWR=COMPATIBLE: tests/pins/pin_data.py). One JSON object.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time

import torch


def best_us(fn, calls: int = 2000, repeats: int = 5) -> float:
    for _ in range(50):
        fn()
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        runs.append((time.perf_counter() - start) / calls * 1e6)
    return round(min(runs), 2)


def costs() -> dict:
    from highway_srl.agents.dqn import DQNConfig, DQNLearner
    from highway_srl.constants import OBS_DIM

    gen = torch.Generator().manual_seed(0)
    take = {}
    for n in (26, 416, 1000, 4000, 8000, 16000, 106496):
        t = torch.randn(2, max(n // 26, 1), 26, generator=gen)
        flat = torch.randint(0, t.numel(), (n,), generator=gen)
        take[n] = {"index_select": best_us(lambda: t.reshape(-1).index_select(0, flat).view(flat.shape), 500),
                   "torch.take": best_us(lambda: torch.take(t, flat), 500)}
    learner = DQNLearner(11, torch.ones(11, 4, dtype=torch.bool), DQNConfig(), "cpu", OBS_DIM, 4, generator=gen)
    flat, idx = learner.exp_avg, torch.tensor([3])
    row, no = flat[3:4].clone(), torch.tensor([[False]])
    row_ops = {"params_per_member": flat.shape[1],
               "index_select": best_us(lambda: flat.index_select(0, idx)),
               "index_copy_": best_us(lambda: flat.index_copy_(0, idx, row)),
               "torch.where": best_us(lambda: torch.where(no, row, row)),
               "lerp_ on the row view": best_us(lambda: flat[3].lerp_(row[0], 0.1))}
    # the compact update's two choices (agents/dqn.py): ReLU's backward on a batch's (1, 256, 256)
    # hidden layer, and Adam on one member's row, elementwise (eight passes) or torch's fused kernel (one); warm
    # here, where in training the rows come from memory (the training step's figures: docs/benchmarks.md)
    grad, hidden = torch.randn(1, 256, 256, generator=gen), torch.randn(1, 256, 256, generator=gen).relu()
    g, m, v, w = (torch.randn(flat.shape[1], generator=gen).abs() for _ in range(4))
    step, size, corr = torch.tensor(5.0), 1e-4 / (1 - 0.9**5), (1 - 0.999**5) ** 0.5

    def elementwise():
        m.lerp_(g, 0.1)
        v.mul_(0.999).addcmul_(g, g, value=0.001)
        w.addcdiv_(m, v.sqrt().div_(corr).add_(1e-8).div_(size), value=-1.0)

    update = {"relu_backward: product with the mask": best_us(lambda: grad * (hidden > 0)),
              "relu_backward: threshold_backward": best_us(lambda: torch.ops.aten.threshold_backward(grad, hidden, 0.0)),
              "adam row: elementwise": best_us(elementwise),
              "adam row: torch._fused_adam_": best_us(lambda: torch._fused_adam_(
                  [w], [g], [m], [v], [], [step], lr=1e-4, beta1=0.9, beta2=0.999, weight_decay=0.0, eps=1e-8,
                  amsgrad=False, maximize=False))}
    return {"what": "costs", "threads": torch.get_num_threads(), "take_flat_us": take, "member_row_us": row_ops,
            "dqn_update_us": update}


def hashes() -> dict:
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(100003, generator=gen) * 3
    m = x[:100000].view(100, 1000)
    ops = {"sin": torch.sin, "cos": torch.cos, "atan2": lambda t: torch.atan2(t, t.flip(0)),
           "asin": lambda t: torch.asin(t.clamp(-1, 1) * 0.9), "exp": torch.exp,
           "log": lambda t: torch.log(t.abs() + 1e-3), "sqrt": lambda t: torch.sqrt(t.abs()), "tanh": torch.tanh,
           "erf": torch.erf, "div": lambda t: t / (t.flip(0) + 10), "sum": lambda t: t.sum(0, keepdim=True),
           "cumsum": lambda t: t.cumsum(0), "mm": lambda t: m @ m.T}
    return {"what": "hashes", "cpu_kernels": torch.backends.cpu.get_cpu_capability(),
            "ops": {name: hashlib.md5(op(x).numpy().tobytes()).hexdigest()[:8] for name, op in ops.items()}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("costs", "hashes"))
    args = p.parse_args()
    print(json.dumps(costs() if args.what == "costs" else hashes()))


if __name__ == "__main__":
    main()
