"""Stable-Baselines3 through highway_srl.sb3 (docs/benchmarks.md): MaskablePPO against unmasked PPO, and
gymnasium.make_vec's batched env against a SyncVectorEnv of single envs.

    OMP_NUM_THREADS=1 python scripts/sb3_bench.py --steps 20000 --episodes 20 [--profile paper]

Needs the [sb3] extra. Prints one JSON line per measurement.
"""

import argparse
import json
import time

import gymnasium
import numpy as np
import torch

import highway_srl
from highway_srl.sb3 import make_vec_env


def evaluate(policy, scenario: str, episodes: int, seed: int, profile: str) -> tuple[float, float, int]:
    """Mean and std of the return of `episodes` first episodes (one per env), and their collision count."""
    envs = highway_srl.make(scenario, num_envs=episodes, vector=True, profile=profile)
    obs, _ = envs.reset(seed=seed)
    total, final = np.zeros(episodes), np.full(episodes, np.nan)
    collisions = 0
    while np.isnan(final).any():
        obs, reward, terminated, truncated, info = envs.step(policy(obs, envs.action_masks()))
        total += reward
        first = (terminated | truncated) & np.isnan(final)
        final[first] = total[first]
        if first.any():
            collisions += int(info["final_info"]["collision"][first].sum())
    return float(final.mean()), float(final.std()), collisions


def train(masked: bool, scenario: str, steps: int, envs: int, seed: int, profile: str):
    from sb3_contrib import MaskablePPO
    from stable_baselines3 import PPO

    algo = MaskablePPO if masked else PPO
    model = algo("MlpPolicy", make_vec_env(scenario, num_envs=envs, seed=seed, profile=profile), n_steps=128, batch_size=256,
                 seed=seed, device="cpu")
    start = time.perf_counter()
    model.learn(steps)
    return model, time.perf_counter() - start


def steps_per_s(env, steps: int) -> float:
    env.reset(seed=0)
    actions = np.ones(env.num_envs, dtype=np.int64)  # Idle
    start = time.perf_counter()
    for _ in range(steps):
        env.step(actions)
    return env.num_envs * steps / (time.perf_counter() - start)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="two-lane")
    p.add_argument("--steps", type=int, default=20_000)
    p.add_argument("--envs", type=int, default=8)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--vec-envs", type=int, default=64)
    p.add_argument("--profile", default="safe", choices=("paper", "safe"),
                   help="rule layer of the training and evaluation envs (safe: the README's MaskablePPO example)")
    args = p.parse_args()
    torch.set_num_threads(1)

    env_id = f"highway-srl/{highway_srl.ENV_IDS[args.scenario]}-v0"
    batched = gymnasium.make_vec(env_id, num_envs=args.vec_envs)
    sync = gymnasium.make_vec(env_id, num_envs=args.vec_envs, vectorization_mode="sync")
    print(json.dumps({"measure": "env-steps/s", "envs": args.vec_envs, "make_vec": round(steps_per_s(batched, 200)),
                      "sync_vector_env": round(steps_per_s(sync, 10))}), flush=True)

    rng = np.random.default_rng(args.seed)
    policies = {"random": lambda obs, masks: rng.integers(0, 4, len(obs))}
    for masked in (True, False):
        model, wall_s = train(masked, args.scenario, args.steps, args.envs, args.seed, args.profile)
        name = "MaskablePPO" if masked else "PPO"
        if masked:
            policies[name] = lambda obs, masks, m=model: m.predict(obs, action_masks=masks, deterministic=True)[0]
        else:
            policies[name] = lambda obs, masks, m=model: m.predict(obs, deterministic=True)[0]
        print(json.dumps({"measure": "train", "algo": name, "steps": args.steps, "wall_s": round(wall_s, 1)}),
              flush=True)
    for name, policy in policies.items():
        mean, std, collisions = evaluate(policy, args.scenario, args.episodes, 10_000, args.profile)
        print(json.dumps({"measure": "return", "policy": name, "episodes": args.episodes, "mean": round(mean, 1),
                          "std": round(std, 1), "collisions": collisions, "profile": args.profile}), flush=True)


if __name__ == "__main__":
    main()
