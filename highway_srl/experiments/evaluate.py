"""`highway-srl evaluate`: deployment metrics (§4.2) of a trained run, greedy, no learning.

C_r: share of episodes without a collision (the paper's Table 5 "C_r"; its text also says R_c), average
speed, deployment reward R_r (formulas under Tables 5-6) and success rate R_s, each with a 95% interval.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import torch

from highway_srl.agents.rollout import policy_step
from highway_srl.constants import TRAFFIC_LEVELS
from highway_srl.experiments.bench import check_sim_memory
from highway_srl.experiments.collisions import Census, DecisionTrace
from highway_srl.experiments.policy import load_policy
from highway_srl.experiments.runs import provenance, write_json
from highway_srl.rules import SafetyLayer, collision_free_rate, mean_interval, success_rate
from highway_srl.rules.episode import EpisodeStats
from highway_srl.scenarios import scenario_spec
from highway_srl.sim import World

EVAL_SEED_BASE = 1_000_000_000  # evaluation episodes never reuse a training seed


def run_episodes(world, method, learner, on_step=None, after_step=None, on_transition=None) -> dict[str, torch.Tensor]:
    """Drive one episode in every env of `world` (no resets); per-env results (B,) on the CPU.

    on_step(t), if given, is called before step t (0-based) with no tensor read (progress display).
    after_step(world, events, alive), if given, is called after each step with the step's events and the
    envs whose episode was still running before it (analyses of the state as the step left it, e.g.
    experiments.collisions). on_transition(view, transition, alive), if given, is called after each step
    with the view the decision was taken from and the step's Transition (what the rule layer allowed and
    what was executed: experiments.collisions.DecisionTrace, which evaluate_run passes)."""
    make_layer = getattr(method, "make_layer", None)  # a Method; duck-typed test policies give layer_options
    layer = make_layer(world.road) if make_layer else SafetyLayer(world.road, **method.layer_options)
    b, dev = world.num_envs, world.device
    stats = EpisodeStats(world.scenario, b, dev, world.max_steps)
    alive = torch.ones(b, dtype=torch.bool, device=dev)
    no_explore = torch.zeros(b, dtype=torch.bool, device=dev)
    view = layer.observe(world)
    counts = getattr(world, "adversary_counts", None)  # our simulator counts group-3 triggers and cut-ins
    adv = {k: torch.zeros(b, dtype=torch.long, device=dev) for k in ("triggers", "cut_ins")} if counts else None
    for step_no in range(world.max_steps):
        if on_step is not None:
            on_step(step_no)
        t = policy_step(method, learner, world, layer, view, no_explore, None, stats, alive=alive)
        if on_transition is not None:
            on_transition(view, t, alive)
        view = t.view
        if after_step is not None:
            after_step(world, t.events, alive)
        if adv is not None:  # each episode's counters as they stood when it ended
            for k, v in counts().items():
                adv[k] = torch.where(alive, v, adv[k])
        alive &= ~(t.events.terminated | t.events.truncated)
        if not bool(alive.any()):
            break
    results = stats.results()
    out = {"collided": results["collision"].cpu(), "success": results["success"].cpu(),
           "avg_speed": results["avg_speed"].cpu(), "deploy_reward": results["deploy_reward"].cpu()}
    if adv is not None:
        out.update({f"adv_{k}": v.cpu() for k, v in adv.items()})
    return out


def evaluation_seeds(trained_seeds: int, episodes: int, seed: int = 0) -> list[int]:
    """The world seeds of an evaluation: `episodes` per trained seed (each seed's model meets the same
    episodes), offset by `seed`, never a training seed."""
    return [EVAL_SEED_BASE + seed * 100_003 + e for _ in range(trained_seeds) for e in range(episodes)]


def summarise(results: dict[str, torch.Tensor], scenario: str) -> dict:
    cr = collision_free_rate(results["collided"])
    out = {
        "episodes": int(results["collided"].numel()),
        "C_r": asdict(cr),
        "avg_speed": asdict(mean_interval(results["avg_speed"])),
        "R_r": asdict(mean_interval(results["deploy_reward"])),
    }
    if scenario_spec(scenario).reports_success:
        out["R_s"] = asdict(success_rate(results["success"]))
    if "adv_triggers" in results:  # group 3: trigger draws and forced cut-ins per episode
        out["adversary"] = {"triggers_per_episode": float(results["adv_triggers"].float().mean()),
                            "cut_ins_per_episode": float(results["adv_cut_ins"].float().mean())}
    return out


def evaluate_run(run: str | Path, scenario: str | None = None, traffics=None, episodes: int = 100,
                 adversarial: bool | None = None, device: str = "cpu", backend: str = "ours", out: str | Path | None = None,
                 seed: int = 0, progress=None, profile: str | None = None, adversary: str | None = None,
                 overwrite: bool = True) -> dict:
    """progress(done, total), if given, is called as the work advances (vector steps on our simulator,
    episodes on the others). profile, adversary: None = the run's own (config.json; runs written before
    these settings existed were trained under "safe" and "mild"). out is written atomically, with overwrite
    False never over a file that exists (FileExistsError). On our simulator each level also gets
    "collisions": what the ego's collisions were (experiments/collisions.py)."""
    policy = load_policy(run, scenario, device, profile)
    cfg, method, learner = policy.config, policy.method, policy.learner
    scenario = cfg.scenario
    adversarial = cfg.adversarial if adversarial is None else adversarial
    adversary = adversary or cfg.adversary
    traffics = list(traffics or [cfg.traffic])
    for t in traffics:
        if t not in TRAFFIC_LEVELS:
            raise ValueError(f"unknown traffic level {t!r}; choose from {', '.join(TRAFFIC_LEVELS)}")
    if episodes < 1:
        raise ValueError(f"episodes must be positive, got {episodes}")
    seeds = len(cfg.seeds)
    if backend == "ours":
        check_evaluation_memory(cfg, traffics, episodes, device, adversarial)
    report = {"run": str(run), "method": cfg.method, "scenario": scenario, "adversarial": adversarial,
              "backend": backend, "episodes_per_level": episodes, "trained_seeds": list(cfg.seeds),
              "profile": method.profile, "adversary": adversary, "levels": {},
              **provenance()}
    for i, traffic in enumerate(traffics):
        env_seeds = evaluation_seeds(seeds, episodes, seed)
        if backend == "ours":
            world = World(scenario, traffic, adversarial, episodes * seeds, device, env_seeds, adversary=adversary)
            n = world.max_steps
            tick = None if progress is None else lambda t, i=i, n=n: progress(i * n + t, len(traffics) * n)
            census, trace = Census(), DecisionTrace(method)
            count = census.level(traffic)

            def after_step(w, events, alive, count=count, trace=trace):  # the census, then the verdicts
                count(w, events, alive)
                trace.after_step(w, events, alive)
            results = run_episodes(world, method, learner, tick, after_step, trace)
            if progress is not None:
                progress((i + 1) * n, len(traffics) * n)
        else:
            tick = None if progress is None else lambda e, i=i: progress(i * episodes + e, len(traffics) * episodes)
            results = _run_backend(backend, scenario, traffic, adversarial, env_seeds, method, learner, episodes, tick)
        level = summarise(results, scenario)
        if backend == "ours":
            level["collisions"] = {**census.summary()[traffic], "by_decision": trace.counts(), **trace.verdicts()}
        level["per_seed"] = {
            str(s): summarise({k: v[i * episodes:(i + 1) * episodes] for k, v in results.items()}, scenario)
            for i, s in enumerate(cfg.seeds)
        } if seeds > 1 else None
        report["levels"][traffic] = level
    if out is not None:
        write_json(Path(out), report, replace=overwrite)
    return report


def check_evaluation_memory(cfg, traffics, episodes: int, device: str, adversarial: bool | None = None) -> None:
    """Refuse (one line, before any work) an evaluation whose world would not fit: on our simulator every
    episode of a level, for every trained seed, is an env of one world (bench.check_sim_memory)."""
    adversarial = cfg.adversarial if adversarial is None else adversarial
    for traffic in traffics or [cfg.traffic]:
        check_sim_memory(cfg.scenario, traffic, episodes * len(cfg.seeds), device, adversarial, "use fewer --episodes")


def _run_backend(backend, scenario, traffic, adversarial, env_seeds, method, learner, episodes, on_episode=None):
    """Simulators we did not write run one env per process: episodes one after another."""
    from highway_srl.backends import make_backend

    if len(env_seeds) != episodes:
        raise ValueError(f"evaluation on backend {backend!r} takes runs trained with one seed")
    parts = []
    for e, env_seed in enumerate(env_seeds):
        if on_episode is not None:
            on_episode(e)
        world = make_backend(backend, scenario, traffic, adversarial, env_seed)
        parts.append(run_episodes(world, method, learner))
        close = getattr(world, "close", None)
        if close is not None:
            close()
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
