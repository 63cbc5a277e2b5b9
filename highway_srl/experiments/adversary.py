"""The learned adversary of the falsifier (`highway-srl falsify --policy learned`): adaptive stress testing.

The breadth search (experiments.falsify) draws the ego's allowed actions at random or by a fixed heuristic
(greedy-ttc). Here the ego learns where the rule layer's holes are: a DQN (agents.dqn.DQNLearner with one
member, agents.replay.ExpertReplay) whose actions are only those the rule layer allows under the chosen
profile (the safety layer's mask: the greedy action is the highest-Q allowed one, the exploring action a
uniform draw among the allowed ones, as the shielded baselines act) and whose reward is

    r = 1 on an ego-avoidable collision (rules.avoidable through the decision trace), else 0,
      + the shaping term gamma Phi(s') - Phi(s), Phi(s) = -shaping min(T, soonest predicted contact) / T,

T = SHAPING_HORIZON_S, the soonest predicted contact the smallest time to collision over the allowed actions
(falsify.predicted_ttc), Phi = 0 after a collision. Why the shaping: ego-avoidable collisions are rare under
the safe profile, so an adversary that only sees the +1 learns nothing until it stumbles on one; the term
rewards closing in on other cars (where every collision happens) and, being a difference of potentials
(Ng, Harada, Russell 1999), leaves the optimal policy that of the +1 alone. `shaping` 0 turns it off.

One adversary is trained per scene, on every chosen level and mode of it (one world of `envs` envs per
level x mode, stepped in turn; `learn_steps` environment steps in all), episodes of the search's length
(`--steps`). Training episodes restart in place, so their collisions are counted but are no replayable
cases. The search then runs as the breadth search does (falsify.falsify, same batches, seeds, report and
cases) with the learned policy as the ego: greedy in the first half of each batch's envs, epsilon-greedy
at `explore` in the rest, every action allowed. Every cause's first case is written as the other policies'
are and `falsify --replay` drives it again.
"""

from __future__ import annotations

import collections
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch

from highway_srl.agents.baselines import highest_allowed, random_allowed
from highway_srl.agents.dqn import DQNConfig, DQNLearner
from highway_srl.agents.methods import Decision
from highway_srl.agents.replay import ExpertReplay
from highway_srl.agents.train_config import check_dqn_config
from highway_srl.constants import OBS_DIM
from highway_srl.experiments.collisions import DecisionTrace
from highway_srl.experiments.falsify import LEARNED, FalsifySettings, check_report_folder, falsify, predicted_ttc
from highway_srl.experiments.runs import write_json
from highway_srl.rules import ACTIONS, SafetyLayer
from highway_srl.sim import World

SHAPING_HORIZON_S = 10.0  # T: contacts predicted further away than this all count as far
TRAIN_SEED_STRIDE = 1_000_003


def default_dqn() -> DQNConfig:
    """The adversary's DQN: Table 2's learning rate and discount, a smaller net and batch than the paper's
    driver (37 -> 128 -> 128 -> 4; a budget of 10^4-10^5 steps on a CPU), epsilon over half the budget."""
    return DQNConfig(batch_size=64, hidden=128, buffer_capacity=50_000, learning_starts=500,
                     target_update_interval=250, exploration_fraction=0.5)


@dataclass
class AdversaryConfig:
    learn_steps: int = 20_000  # environment steps of training per scene
    envs: int = 16  # per training world (one per level x mode)
    explore: float = 0.1  # epsilon of the exploring half of the search's episodes
    shaping: float = 0.1  # the potential's scale (0: the +1 alone)
    replay_ratio: float = 0.25  # gradient steps per environment step
    dqn: DQNConfig = field(default_factory=default_dqn)

    def check(self) -> None:
        for name in ("learn_steps", "envs"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name.replace('_', '-')} must be a positive integer, got {value!r}")
        for name, hi in (("explore", 1.0), ("shaping", 1.0), ("replay_ratio", 16.0)):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not 0.0 <= value <= hi:
                raise ValueError(f"{name.replace('_', '-')} must be a number from 0 to {hi}, got {value!r}")
        check_dqn_config(self.dqn)


class AdversaryActions:
    """What the decision trace reads of the adversary: the action names and the safe mask (the rule layer's)."""

    action_names = ACTIONS

    @staticmethod
    def safe_mask(model) -> torch.Tensor:
        return model.mask


def act(net, model, explore: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """(B,) the adversary's actions on a rule-layer model step: the highest-Q allowed action of net (the
    learner's online MLPEnsemble), a uniform allowed one where explore (B,) bool. Only allowed actions."""
    mask = model.mask
    with torch.no_grad():
        greedy = highest_allowed(net(model.obs)[0], mask)
    drawn = random_allowed(mask, torch.rand(mask.shape, generator=generator))
    return torch.where(explore, drawn, greedy)


def potential(model, ego_vx: torch.Tensor, shaping: float) -> torch.Tensor:
    """(B,) Phi(s) = -shaping min(T, soonest predicted contact over the allowed actions) / T."""
    ttc = torch.where(model.mask, predicted_ttc(model, ego_vx), SHAPING_HORIZON_S).amin(1)
    return -shaping * ttc.clamp(max=SHAPING_HORIZON_S) / SHAPING_HORIZON_S


def avoidable_reward(records: list[dict], batch: int) -> torch.Tensor:
    """(B,) 1.0 in the env of each judged ego-avoidable collision record (DecisionTrace's), else 0."""
    reward = torch.zeros(batch)
    for rec in records:
        reward[rec["env"]] = float(rec["ego_avoidable"])
    return reward


class AdversaryWorld:
    """One training world: the rule layer, the decision trace that judges its collisions, and the view the
    next action is chosen on. step() applies actions and returns the transition with the adversary's reward;
    ended episodes restart in place."""

    def __init__(self, world: World, profile: str, shaping: float = 0.0, gamma: float = 0.99):
        self.world, self.shaping, self.gamma = world, shaping, gamma
        self.layer = SafetyLayer(world.road, profile=profile)
        self.trace = DecisionTrace(AdversaryActions())
        self.view = self.layer.observe(world)
        self.episodes, self.records = 0, []  # episodes ended; the judged records of their collisions

    def step(self, action: torch.Tensor) -> dict[str, torch.Tensor]:
        """obs, action, reward, next_obs, done (termination only) of one step of every env."""
        view, world = self.view, self.world
        events = world.step(*self.layer.act(action))
        self.trace.keep_decision(view, Decision(action, torch.zeros_like(action), None))
        self.trace.keep_state(world)
        nxt = self.layer.observe(world)
        records = self.trace.judge_ended(world, events.collision)
        reward = avoidable_reward(records, world.num_envs)
        if self.shaping:
            after = torch.where(events.terminated, 0.0, potential(nxt.primary, nxt.snapshot.ego_vx, self.shaping))
            reward += self.gamma * after - potential(view.primary, view.snapshot.ego_vx, self.shaping)
        done = events.terminated | events.truncated
        out = {"obs": view.primary.obs, "action": action, "reward": reward, "next_obs": nxt.primary.obs,
               "done": events.terminated}
        if bool(done.any()):
            self.episodes += int(done.sum())
            self.records += records
            world.reset(done)
            self.layer.reset(done)
            self.trace.episodes_restart(world, done)
            nxt = self.layer.observe(world)
        self.view = nxt
        return out


def train_adversary(scene: str, settings: FalsifySettings, config: AdversaryConfig,
                    progress=None) -> tuple[DQNLearner, dict]:
    """The adversary of one scene (module docstring), trained for config.learn_steps environment steps;
    returns the learner and a summary (training episodes ended, their collisions, the ego-avoidable ones, the
    collisions by reason, seconds; learn_steps rounded up to whole vector steps of `envs`).
    progress(steps, learn_steps), if given, is called every 100 vector steps."""
    start, seed = time.perf_counter(), settings.seed
    cfg = replace(config.dqn, total_steps=config.learn_steps)  # epsilon's schedule spans the budget
    # world seeds apart from the search's (seed + batch start): it never trains on the episodes it is judged on
    worlds = [AdversaryWorld(World(scene, level, adversarial, config.envs, "cpu", seed + TRAIN_SEED_STRIDE * (i + 1),
                                   max_steps=settings.steps, adversary=settings.adversary),
                             settings.profile, config.shaping, cfg.gamma)
              for i, (adversarial, level) in enumerate((a, lv) for a in settings.modes for lv in settings.levels)]
    learner = DQNLearner(1, torch.ones(1, len(ACTIONS), dtype=torch.bool), cfg, "cpu", OBS_DIM, len(ACTIONS),
                         generator=torch.Generator().manual_seed(seed))
    replay = ExpertReplay(1, OBS_DIM, cfg.buffer_capacity)
    gen, member = torch.Generator().manual_seed(seed + 1), torch.zeros(1, dtype=torch.long)
    steps, credit, vector_steps = 0, 0.0, 0
    while steps < config.learn_steps:
        cell = worlds[vector_steps % len(worlds)]
        explore = torch.rand(config.envs, generator=gen) < cfg.epsilon(steps)
        t = cell.step(act(learner.online, cell.view.primary, explore, gen))
        replay.add(member.expand(config.envs), t["obs"], t["action"], t["reward"], t["next_obs"], t["done"])
        steps, vector_steps = steps + config.envs, vector_steps + 1
        if steps >= cfg.learning_starts and int(replay.size[0]) >= cfg.batch_size:
            credit += config.replay_ratio * config.envs
            for _ in range(int(credit)):
                learner.update(member, replay.sample(member, cfg.batch_size, gen))
            credit -= int(credit)
        if progress is not None and vector_steps % 100 == 0:
            progress(min(steps, config.learn_steps), config.learn_steps)
    records = [rec for cell in worlds for rec in cell.records]
    return learner, {"scene": scene, "learn_steps": steps, "episodes": sum(cell.episodes for cell in worlds),
                     "collisions": len(records), "ego_avoidable": sum(rec["ego_avoidable"] for rec in records),
                     "by_reason": dict(collections.Counter(rec["reason"] for rec in records).most_common()),
                     "seconds": round(time.perf_counter() - start, 1)}


class LearnedPolicy:
    """The trained adversary as a falsify ego: pick(view, generator) -> (B,) allowed actions, greedy in the
    first half of the batch's envs and epsilon-greedy at `explore` in the rest."""

    def __init__(self, net, explore: float):
        self.net, self.explore = net, explore

    def __call__(self, view, generator: torch.Generator) -> torch.Tensor:
        mask = view.primary.mask
        b = mask.shape[0]
        eps = torch.where(torch.arange(b) < (b + 1) // 2, 0.0, self.explore)
        return act(self.net, view.primary, torch.rand(b, generator=generator) < eps, generator)


def falsify_learned(settings: FalsifySettings, config: AdversaryConfig | None = None, out: str | Path | None = None,
                    progress=None, processes: int = 1) -> dict:
    """Train an adversary per scene (train_adversary), then the search of falsify.falsify with it as the
    ego; the report (falsify's, with "adversary": the config and each scene's training summary), written to
    out/report.json with the cases as falsify writes them. progress(stage, done, total): stage is
    "train SCENE" or "search"."""
    config = config or AdversaryConfig()
    if settings.policy != LEARNED:
        raise ValueError(f"the learned adversary runs under policy {LEARNED!r}, got {settings.policy!r}")
    settings.check()
    config.check()
    if out is not None:
        check_report_folder(Path(out))
    policies, trained = {}, []
    for scene in settings.scenes:
        report_train = None if progress is None else (lambda d, n, s=scene: progress(f"train {s}", d, n))
        learner, summary = train_adversary(scene, settings, config, report_train)
        policies[scene] = LearnedPolicy(learner.online, config.explore)
        trained.append(summary)
    search = None if progress is None else (lambda d, n: progress("search", d, n))
    report = falsify(settings, out, search, processes, policies=policies)
    report["adversary"] = {"config": asdict(config), "training": trained}
    if out is not None:
        write_json(Path(out) / "report.json", report)
    return report
