"""Behaviour pins: fingerprints of the simulator + rule layer and of a short training run of every method.

Written before the structure refactor (issue: one rollout, one registry, scenario specs) on the code it
refactors, so that a refactor that changes any number is caught. A deliberate behaviour change updates
the golden file with `python tests/pins/pin_data.py --write` and says why in its commit.

The fingerprints are bit-exact, and the last bits of torch's CPU arithmetic depend on the machine: torch's
own kernels round differently on AVX2 and AVX-512 (sums, exp/log), and the MKL it calls for matrix products
and for exp, log, sqrt, asin, tanh and erf picks its code by CPU model (another answer on an Intel AVX-512
host than on an AMD one, under either torch setting). So they are computed in a child process with the
settings of PINNED_ENV: torch's AVX2 kernels and MKL's reproducible mode COMPATIBLE (its documented way
to give the same results on every x86 CPU, Intel or not; slower, which is why only the pins run in it).
`python tests/pins/pin_data.py trajectories|methods` prints one kind as JSON (what tests/pins/test_pins.py
runs).

Even so, an AMD host computes other last bits than an Intel one (all eight trajectories differ on a 2-vCPU
AMD EPYC at the same commit; MKL's vector math, e.g. exp, gives one answer there whatever MKL_CBWR says).
So golden.json keeps the fingerprints per CPU vendor (host_key), and a host whose vendor has none recorded
skips the pins, saying so. `--write` (a deliberate behaviour change) records this host's and drops the
other vendors' (they no longer hold); `--add-host` adds this host's beside them, for a commit whose
behaviour is unchanged since they were recorded.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import sys
from pathlib import Path

# read by torch and MKL once, when they start: set for the child process before it imports torch
PINNED_ENV = {"OMP_NUM_THREADS": "1"}
if platform.machine().lower() in ("x86_64", "amd64"):
    PINNED_ENV.update(ATEN_CPU_CAPABILITY="avx2", MKL_CBWR="COMPATIBLE")
if __name__ == "__main__":
    os.environ.update(PINNED_ENV)

import torch  # noqa: E402

GOLDEN = Path(__file__).with_name("golden.json")
SCENARIOS = ("two-lane", "multi-lane", "merge", "exit")
PIN_STEPS = 400
PIN_ENVS = 16


def trajectory_hash(scenario: str, adversarial: bool, steps: int = PIN_STEPS, envs: int = PIN_ENVS) -> str:
    """sha256 over the world state, the step events and the rule layer's view after every step of
    `envs` level-C envs driven by a fixed action pattern through the mapped rule layer (with resets)."""
    from highway_srl.rules import SafetyLayer
    from highway_srl.sim import World

    # the settings the trajectories were recorded with, named (not the library's defaults, which may change)
    world = World(scenario, "C", adversarial, envs, "cpu", seed=7, adversary="mild")
    layer = SafetyLayer(world.road, profile="safe")
    h = hashlib.sha256()
    env = torch.arange(envs)
    for t in range(steps):
        step = layer.observe(world)
        action = (env + t // 3) % 4
        lane, speed = layer.act(action, step.two_models & (env % 2 == 0))
        events = world.step(lane, speed)
        for name in sorted(vars(world.state)):
            h.update(vars(world.state)[name].contiguous().numpy().tobytes())
        for name in ("collision", "success", "failure", "terminated", "truncated", "sv_collisions"):
            h.update(getattr(events, name).contiguous().numpy().tobytes())
        h.update(step.primary.obs.contiguous().numpy().tobytes())
        h.update(step.primary.mask.contiguous().numpy().tobytes())
        done = events.terminated | events.truncated
        if bool(done.any()):
            world.reset(done)
            layer.reset(done)
    return h.hexdigest()


PIN_METHODS = (
    ("moe-rm-srl", {}), ("moe-rm-srl", {"no_mapping": True}), ("moe-rm-srl", {"no_moe": True}),
    ("moe-rm-srl", {"no_rm": True}), ("rl", {}), ("sr-rl", {}), ("rm-rl", {}), ("mp-rl", {}), ("lm-rl", {}),
    ("et-rl", {}), ("rule-based", {}),
)


def method_fingerprint(method: str, options: dict, tmp: Path) -> dict:
    """A short train (1300 env steps, 4 envs: every env ends an episode, updates from step 128) and a 6-episode evaluation at level C;
    returns the training metrics, a hash of the saved model and the evaluation summary."""
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.train_config import TrainConfig
    from highway_srl.experiments.evaluate import evaluate_run
    from highway_srl.experiments.train import train_run

    name = method + "".join(f"-{k}" for k in sorted(options))
    out = tmp / name
    cfg = TrainConfig(method=method, scenario="two-lane", traffic="C", steps=1300, envs=4, seeds=(0,),
                      options=dict(options), dqn=DQNConfig(learning_starts=128, batch_size=32, buffer_capacity=4096, total_steps=1300))
    train_run(cfg, out, progress=False)
    metrics = json.loads((out / "metrics.json").read_text())
    keep = {k: metrics[k] for k in ("per_seed", "mean", "member_usage")}
    keep["episodes.jsonl"] = hashlib.sha256((out / "episodes.jsonl").read_bytes()).hexdigest()
    model = hashlib.sha256()
    for f in sorted((out / "model").glob("*.safetensors")):
        from safetensors.torch import load_file

        tensors = load_file(f)
        for k in sorted(tensors):
            model.update(k.encode())
            model.update(tensors[k].contiguous().numpy().tobytes())
    report = evaluate_run(out, traffics=["C"], episodes=6)
    level = report["levels"]["C"]
    return {"train": keep, "model": model.hexdigest(),
            "eval": {k: level[k] for k in ("C_r", "avg_speed", "R_r")}}


def method_key(method: str, options: dict) -> str:
    return method + "".join(f"+{k}" for k in sorted(options))


def compute(kind: str, tmp: Path) -> dict:
    """Every fingerprint of one kind ("trajectories" or "methods"), by key."""
    if kind == "trajectories":
        return {f"{scenario}/{'adv' if adversarial else 'nom'}": trajectory_hash(scenario, adversarial)
                for scenario in SCENARIOS for adversarial in (False, True)}
    return {method_key(method, options): method_fingerprint(method, options, tmp) for method, options in PIN_METHODS}


def host_key() -> str:
    """The CPU vendor the fingerprints are recorded for (GenuineIntel, AuthenticAMD, ...), else the machine."""
    from highway_srl.study.runner import cpuinfo

    return cpuinfo("vendor_id") or platform.machine() or "unknown"


def golden_for_host(golden: dict) -> dict | None:
    """This host's fingerprints in golden.json's {vendor: {kind: ...}}, None if none are recorded for it."""
    return golden.get(host_key())


def check_settings() -> None:
    """Exit with one line if the settings of PINNED_ENV did not take (torch started before they were set)."""
    capability = torch.backends.cpu.get_cpu_capability()
    if "ATEN_CPU_CAPABILITY" in PINNED_ENV and capability != "AVX2":
        sys.exit(f"the pins need torch's AVX2 CPU kernels, this process runs {capability}")


if __name__ == "__main__":
    import tempfile

    kinds = [a for a in sys.argv[1:] if a in ("trajectories", "methods")] or ["trajectories", "methods"]
    check_settings()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as d:
        data = {kind: compute(kind, Path(d)) for kind in kinds}
    text = json.dumps(data, indent=1, sort_keys=True)
    write, add = "--write" in sys.argv, "--add-host" in sys.argv
    if write or add:
        if len(kinds) != 2:
            sys.exit("--write and --add-host record both kinds: drop trajectories/methods")
        golden = json.loads(GOLDEN.read_text()) if add and GOLDEN.exists() else {}
        golden[host_key()] = data
        from highway_srl.agents.checkpoint import write_atomic

        write_atomic(GOLDEN, (json.dumps(golden, indent=1, sort_keys=True) + "\n").encode())
    print(text)
