"""What does one of the safe profile's additions cost the rule layer: SafetyLayer.observe with the addition off
and on (with --act, observe and then act on a fixed random action each, for the additions that work in act),
alternated in one process on one world (its state fixed, so both read the same traffic).

    OMP_NUM_THREADS=1 python scripts/rule_layer_cost.py --option lanes_by_body --scenario multi-lane --envs 4096

Prints one JSON object: the median milliseconds per observe (or observe + act) of each side over --rounds
rounds of --repeats, and their ratio.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from highway_srl.rules import ACTIONS, PROFILES, SafetyLayer
from highway_srl.sim import World


def measure(option: str, scenario: str, envs: int, rounds: int, repeats: int, act: bool = False) -> dict:
    world = World(scenario, "C", num_envs=envs, seed=0)
    layers = {on: SafetyLayer(world.road, profile="safe", **{option: on}) for on in (False, True)}
    actions = torch.randint(0, len(ACTIONS), (envs,), generator=torch.Generator().manual_seed(0))
    times: dict[bool, list[float]] = {False: [], True: []}

    def once(layer: SafetyLayer) -> None:
        layer.observe(world)
        if act:
            layer.act(actions)

    for layer in layers.values():
        once(layer)  # warm up
    for _ in range(rounds):
        for on, layer in layers.items():
            start = time.perf_counter()
            for _ in range(repeats):
                once(layer)
            times[on].append((time.perf_counter() - start) / repeats * 1e3)
    off, on = statistics.median(times[False]), statistics.median(times[True])
    what = "observe_act" if act else "observe"
    return {"option": option, "scenario": scenario, "envs": envs, "rounds": rounds, "repeats": repeats,
            "threads": torch.get_num_threads(), f"ms_per_{what}_off": round(off, 3), f"ms_per_{what}_on": round(on, 3),
            "ratio_on_off": round(on / off, 3)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="rule_layer_cost.py", description=__doc__.splitlines()[0])
    booleans = [f.name for f in PROFILES["safe"].__dataclass_fields__.values() if f.type in (bool, "bool")]
    p.add_argument("--option", required=True, choices=booleans, help="a boolean addition of the safe profile")
    p.add_argument("--scenario", default="multi-lane")
    p.add_argument("--envs", type=int, default=4096)
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--act", action="store_true", help="time observe and act (for additions that work in act)")
    args = p.parse_args(argv)
    if min(args.envs, args.rounds, args.repeats) < 1:
        p.error("--envs, --rounds and --repeats must be positive")
    try:
        print(json.dumps(measure(args.option, args.scenario, args.envs, args.rounds, args.repeats, args.act)))
    except ValueError as err:
        p.error(str(err))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
