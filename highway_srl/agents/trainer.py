"""The training loop (Algorithm 1), batched over envs and seeds on one device.

One vector step: observe (rules) -> act (method) -> control mapping -> world step -> observe the next
state -> reward -> store in the acting member's buffer -> episode bookkeeping and resets -> DQN updates
of the members that acted. Everything stays on the trainer's device. The compact form (the CPU's eager
default) reads back whether an env is done and which members to update; the static form (CUDA, compiled)
reads nothing but the finished episodes, every few vector steps (Trainer). A step's random numbers are drawn
before it (Trainer.draw), so that the static step is one traced graph (Trainer.vector_step).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import torch

from highway_srl.agents.checkpoint import policy_tensors, split_policy_tensors
from highway_srl.agents.dqn import DQNLearner, UpdateLog, UpdateStats
from highway_srl.agents.methods import Method
from highway_srl.agents.registry import make_method
from highway_srl.agents.replay import ExpertReplay
from highway_srl.agents.rollout import policy_step
from highway_srl.agents.train_config import MAX_SEED, TrainConfig, check_config  # noqa: F401 (MAX_SEED: the CLI reads it here)
from highway_srl.constants import OBS_DIM
from highway_srl.rules.episode import RESULT_FIELDS, EpisodeStats, FinishedEpisodes, episode_row
from highway_srl.sim import World
from highway_srl.sim.adversary import ADVERSARIES
from highway_srl.sim.compiled import WARM_CALLS, call_settled, compile_options, uses_cuda_graphs
from highway_srl.sim.state import WorldState


# resume/ keys of the episode accumulators (EpisodeStats field -> key), kept from the first checkpoints
EPISODE_KEYS = {"ret": "episode.ep_return", "deploy": "episode.ep_deploy", "speed": "episode.ep_speed",
                "length": "episode.ep_len", "collision": "episode.ep_collision", "success": "episode.ep_success",
                "rm": "episode.ep_rm_return"}
# the update log's sums since the last row of scalars.csv (a resumed run's next row averages the same updates)
UPDATE_LOG_KEYS = ("counters.update_log_sums", "counters.update_log_count")
# keys a resume checkpoint may lack (written before they existed); the loader fills them in
# per seed, the training collisions by verdict: ego-avoidable, unavoidable, not judged (VERDICT_COLUMNS)
VERDICT_KEY = "counters.collision_verdicts"
VERDICT_COLUMNS = ("ego_avoidable", "unavoidable", "not_judged")
OPTIONAL_KEYS = frozenset({"episode.ep_rm_return", *UPDATE_LOG_KEYS, VERDICT_KEY})


@dataclass
class Draws:
    """The random numbers of one vector step (Trainer.draw), drawn with the trainer's generator before the
    step in the order the step reads them; the step draws nothing itself, so a traced step takes them as
    inputs (dynamo does not take a torch.Generator)."""

    explore: torch.Tensor  # (B,) bool: the ε-greedy draw, u < ε
    act: torch.Tensor | None  # (B, method.draw_width) uniforms of the method's random actions; None: it has none
    learn: bool  # the step updates (the env steps, this one counted, reached learning_starts)
    update: torch.Tensor | None  # static form: (rounds, K, batch) uniforms of the update rounds' samples, None
    # when it does not learn or trains no member; the compact form samples in its update (how many: a host read)


@dataclass
class Episode:
    seed: int
    step: int  # environment steps of this seed when the episode ended
    ret: float  # training return (the reward the learner saw, on the method's own scale)
    length: int
    collision: bool
    avg_speed: float
    success: bool
    deploy_reward: float  # the paper's R_r of the episode
    rm_return: float  # the paper's RM reward summed over the episode: T_r on one scale for every method
    ego_avoidable: bool | None = None  # a collision's verdict (rules.avoidable); None: no collision or not judged


class Trainer:
    """One vector step at a time (step), in one of two forms with the same semantics:

    compact (the CPU's eager default): resets, episode rows and the members to update are chosen by what
    the step produced (host reads: whether any env is done, which members are owed updates, how many rounds);
    static (config.static; on CUDA and whenever compiled): every reset is a masked select of freshly
    spawned state, and every member the method can train takes a fixed number of update rounds under a mask
    (ceil(replay_ratio x envs): the most one member can be owed), each on its own batch. Nothing in the
    static step reads the device (the rule layer and the methods run in their static forms too), and its
    random numbers are drawn before it (draw), so vector_step is one graph with no break
    (tests/agents/test_compiled_training.py), which config.compile compiles (compile_vector_step).

    In both, finished episodes wait on the device (FinishedEpisodes) and are read every drain_every vector
    steps (step returns them then) or by drain(); state_dict needs them drained (train drains before each
    checkpoint, so checkpoints and resumes stay exact)."""

    def __init__(self, config: TrainConfig, drain_every: int = 1):
        cfg = config
        check_config(cfg)
        self.config = cfg
        self.num_seeds = len(cfg.seeds)
        self.batch = cfg.envs * self.num_seeds
        env_seeds = [s * 1_000_003 + e for s in cfg.seeds for e in range(cfg.envs)]
        # compiled, the world's step is traced into the trainer's graphs (compile_vector_step), not on its own
        self.world = World(cfg.scenario, cfg.traffic, cfg.adversarial, self.batch, cfg.device, env_seeds,
                           adversary=cfg.adversary)
        self.device = self.world.device
        self.static = cfg.static if cfg.static is not None else bool(cfg.compile) or self.device.type == "cuda"
        if cfg.compile and not self.static:
            raise ValueError("compile needs the static step (static=False was set)")
        self.world.static = self.static
        self.method: Method = make_method(cfg.method, cfg.scenario, self.num_seeds, cfg.options, cfg.profile)
        self.layer = self.method.make_layer(self.world.road)
        self.layer.static = self.static
        self.learner = DQNLearner(
            self.method.num_members, self.method.action_mask(), cfg.dqn, self.device, OBS_DIM, self.method.out_dim,
            generator=torch.Generator(device="cpu").manual_seed(cfg.seeds[0]),
        )
        self.replay = ExpertReplay(self.method.num_members, OBS_DIM, cfg.dqn.buffer_capacity, self.device,
                                   with_cost=self.method.uses_cost)
        self.gen = torch.Generator(device=self.device).manual_seed(cfg.seeds[0] + 12345)
        self.vector_steps = 0
        self.step_count = torch.zeros((), dtype=torch.long, device=self.device)
        # acting member counts, slot 0 = the final fallback (no expert)
        self.usage = torch.zeros(self.method.num_members + 1, dtype=torch.long, device=self.device)
        self.update_log = UpdateLog(self.device)  # loss, Q, TD error since the last row of scalars.csv
        # replay_ratio: updates owed to each member, carried over while below one (fractional ratios)
        self.update_credit = torch.zeros(self.method.num_members, dtype=torch.float64, device=self.device)
        # the deployment reward R_r is tracked for every method alike
        self.stats = EpisodeStats(cfg.scenario, self.batch, self.device, self.world.max_steps)
        self.drain_every = max(1, int(drain_every))
        self.finished = FinishedEpisodes(self.batch * self.drain_every, len(RESULT_FIELDS), self.device)
        # the static form's fixed update: these members, this many rounds (a member acts in at most `envs`
        # envs of a vector step and carries less than one update over, so it is never owed more)
        self.trained = self.method.trained_members(self.device)
        self.static_rounds = math.ceil(cfg.replay_ratio * cfg.envs) if self.trained.numel() else 0
        self.method.start(self.batch, self.device, self.static)
        self._view = self.layer.observe(self.world)
        # set by train_run in the compact form: judges each collision where its episode ends (judge_collisions)
        self.collision_trace = None
        self.verdicts: dict[tuple[int, int], bool] = {}  # (env, vector step) -> ego-avoidable, until drained
        self.verdict_counts = torch.zeros(self.num_seeds, len(VERDICT_COLUMNS), dtype=torch.long)  # host counts
        compiled = cfg.compile and compile_vector_step(self, cfg.compile, cfg.compile_unrolled)
        self.run_step = compiled or self.vector_step

    @property
    def current(self):
        """The rule layer's view (SafetyStep) of the current state: what the next step decides on. The static
        form observes it at the start of each step (a traced step carries no view over), so here on demand."""
        if self._view is None:
            self._view = self.layer.observe(self.world)
        return self._view

    @property
    def env_steps(self) -> int:
        """Environment steps per seed so far."""
        return self.vector_steps * self.config.envs

    # ------------------------------------------------------------------ one vector step
    def step(self) -> list[Episode]:
        """One vector step; returns the episodes drained now (every drain_every steps; [] in between)."""
        self.run_step(self.draw())
        self.vector_steps += 1
        return self.drain() if self.vector_steps % self.drain_every == 0 else []

    def draw(self) -> Draws:
        """The next vector step's random numbers, in the order (and shapes) the step reads them: the ε draw
        (B,), the method's uniforms (B, draw_width), the static update rounds' (rounds, K, batch) when it
        learns. ε and whether it learns are host numbers of the step count (so never read in the step)."""
        cfg = self.config
        explore = torch.rand(self.batch, generator=self.gen, device=self.device) < cfg.dqn.epsilon(self.env_steps)
        width = self.method.draw_width
        act = torch.rand(self.batch, width, generator=self.gen, device=self.device) if width else None
        learn = (self.vector_steps + 1) * cfg.envs >= cfg.dqn.learning_starts
        update = None
        if self.static and learn and self.static_rounds:
            # all rounds' draws at once, one per (round, member, sample): every member samples every round
            update = torch.rand(self.static_rounds, self.trained.shape[0], cfg.dqn.batch_size, generator=self.gen,
                                device=self.device)
        return Draws(explore, act, learn, update)

    def vector_step(self, draws: Draws) -> None:
        """One vector step at the given draws, all but the host's step count (step). The static form reads
        nothing back and no Python number that changes from step to step: one graph (compile_vector_step)."""
        if self.static:
            masks, cost, done = self.collect_static(draws)
            for i in range(0 if masks is None else masks.shape[0]):  # round i: one batch per member owed > i
                self.static_round(draws.update[i], masks[i])
        else:
            acted, cost, done = self.collect(draws)
            if draws.learn:
                self._update(acted)
        self.method.after_step(self, cost, done)

    def collect(self, draws: Draws) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """The vector step up to its updates: act, step the world, store, account, reset. Returns the member
        that acted in each env (B,) and the method's after_step arguments: the cost signal (B,) or None, and
        the envs whose episode ended (B,) bool."""
        cfg, world, layer = self.config, self.world, self.layer
        cur = layer.observe(world) if self.static else self.current
        t = policy_step(self.method, self.learner, world, layer, cur, draws.explore, draws.act, self.stats, train=True)
        decision, events, nxt = t.decision, t.events, t.view
        if self.collision_trace is not None:  # device clones only
            self.collision_trace.keep_decision(cur, decision)
            self.collision_trace.keep_state(world)
        self.usage.index_add_(0, decision.member + 1, torch.ones_like(decision.member))
        model = cur.select(decision.use_second)
        self.method.store(self.replay, decision, model.obs, t.reward, nxt.primary.obs, events.terminated, t.cost,
                          share=cfg.share_transitions)
        done = events.terminated | events.truncated
        self.step_count += 1  # the step count on the device: tags the episodes without a host-to-device copy
        self.finished.record(done, self.stats.rows(), self.step_count)
        self.stats.restart(done)
        if self.static:
            world.reset_where(done)
            layer.reset(done)
            self._view = None  # the next step observes the new state
        else:
            if bool(done.any()):
                self.judge_collisions(events.collision)
                world.reset(done)
                layer.reset(done)
                if self.collision_trace is not None:  # a new episode's decisions are judged on their own
                    self.collision_trace.episodes_restart(world, done)
                nxt = layer.observe(world)
            self._view = nxt
        return decision.member, t.cost, done

    def collect_static(self, draws: Draws) -> tuple[torch.Tensor | None, torch.Tensor | None, torch.Tensor]:
        """The static form's collect with the owed updates turned into the rounds' masks: (rounds, K) bool,
        round i updates the trained members owed more than i steps (None when the step does not update);
        then the cost and done of collect. The first graph of the split compiled step (compile_vector_step)."""
        acted, cost, done = self.collect(draws)
        masks = self.round_masks(acted, draws.update.shape[0]) if draws.learn and draws.update is not None else None
        return masks, cost, done

    def round_masks(self, acted: torch.Tensor, rounds: int) -> torch.Tensor:
        """(rounds, K) bool: round i of the static updates steps the trained members owed more than i
        steps after a vector step in which acted (B,) names each env's acting member (owed_updates)."""
        need = self.owed_updates(acted)[self.trained]
        return need > torch.arange(rounds, device=need.device)[:, None]

    def judge_collisions(self, collision: torch.Tensor) -> None:
        """Where episodes end (compact form, before the reset): the ego-avoidable verdict of each collision
        (B,) by collision_trace, kept by env and vector step until drain hands it to the episode."""
        if self.collision_trace is None:
            return
        records = self.collision_trace.judge_ended(self.world, collision)
        if records:
            tag = int(self.step_count)
            self.verdicts.update({(rec["env"], tag): rec["ego_avoidable"] for rec in records})

    def drain(self) -> list[Episode]:
        """The finished episodes not yet read, in the order they ended (one host read)."""
        cfg = self.config
        values, tags = self.finished.drain()
        episodes = [Episode(cfg.seeds[r.env // cfg.envs], tag * cfg.envs, r.ret, r.length, r.collision, r.avg_speed,
                            r.success, r.deploy_reward, r.rm_return, self.verdicts.pop((r.env, tag), None))
                    for r, tag in zip(map(episode_row, values), tags)]
        for e in episodes:
            if e.collision:
                column = 2 if e.ego_avoidable is None else int(not e.ego_avoidable)
                self.verdict_counts[cfg.seeds.index(e.seed), column] += 1
        return episodes

    def owed_updates(self, acted: torch.Tensor) -> torch.Tensor:
        """(M,) long on the device: the gradient steps each member takes after a vector step in which acted
        (B,) names the member that acted in each env (-1: none). No host read; credits carry on the device.

        Algorithm 1 takes one gradient step on a batch of n_b from the acting expert's buffer after every
        environment step. With B envs a vector step is B environment steps, so member m gets
        replay_ratio x (number of envs it acted in) steps: at ratio 1, B per vector step in all, spread over
        the members exactly as B single-env steps of Algorithm 1 would spread them. The fallback (-1) owns
        no transition and takes none (Algorithm 1's j != 0); a member whose buffer holds less than a batch
        takes none yet and owes nothing. Fractions carry over in update_credit."""
        cfg = self.config
        count = torch.zeros(self.method.num_members, dtype=torch.long, device=self.device)
        count.index_add_(0, acted.clamp(min=0), (acted >= 0).long())
        eligible = self.method.updatable(count, self.replay.size, cfg.dqn.batch_size)
        owed = self.update_credit + cfg.replay_ratio * count.double()
        updates = owed.floor()
        self.update_credit = torch.where(eligible, owed - updates, self.update_credit)
        return torch.where(eligible, updates, 0.0).long()

    def update_counts(self, acted: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """owed_updates as (members (K,), updates (K,)) of the members owed at least one step (host read)."""
        updates = self.owed_updates(acted)
        members = updates.nonzero().squeeze(1)
        return members, updates[members]

    def _update(self, acted: torch.Tensor) -> None:
        """The compact form's updates after a vector step in which acted (B,) names each env's acting
        member: the owed members, sampled with the generator. (The static form: collect_static's masks,
        static_round.)"""
        cfg = self.config
        members, updates = self.update_counts(acted)
        rounds = int(updates.max()) if updates.numel() else 0
        for i in range(rounds):  # round i: every member owed more than i steps, one batch each
            take = members[updates > i]
            batch = self.replay.sample(take, cfg.dqn.batch_size, self.gen)
            self.update_log.add(self.method.update(self.learner, take, batch))

    def static_round(self, u: torch.Tensor, mask: torch.Tensor) -> None:
        """One round of the static form's updates: every trained member samples its buffer at u (K, batch)
        and steps where mask (K,) is True; their statistics go to the update log."""
        self.update_log.add(UpdateStats(*self.update_round(self.trained, u, mask)), mask)

    def update_round(self, members: torch.Tensor, u: torch.Tensor, mask: torch.Tensor) -> tuple:
        """One static update round: members (K,) each sample their buffer at u (K, batch) and step where
        mask (K,) is True. Returns the UpdateStats fields (a tuple: what a compiled graph returns)."""
        stats = self.method.update(self.learner, members, self.replay.sample_at(members, u), mask)
        return stats.loss, stats.q_mean, stats.td_error

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, torch.Tensor]:
        """Everything a resumed run needs to continue exactly: weights, targets, Adam moments, counters,
        replay buffers, the worlds' state, the rule layer's target lanes, episode accumulators and RNG.
        Finished episodes not yet drained are not part of it: drain() first (a RuntimeError otherwise)."""
        if int(self.finished.count):
            raise RuntimeError("finished episodes are waiting on the device: drain() before state_dict()")
        state = policy_tensors(self.learner, self.method)
        state.update(self.replay.state_dict())
        for name, value in vars(self.world.state).items():
            state[f"world.{name}"] = value
        state["layer.target_lane"] = self.layer.target_lane
        for name, value in self.stats.state_dict().items():
            state[EPISODE_KEYS[name]] = value
        state["rng.trainer"] = self.gen.get_state()
        state["counters.vector_steps"] = torch.tensor([self.vector_steps])
        state["counters.usage"] = self.usage
        state["counters.update_credit"] = self.update_credit
        state[UPDATE_LOG_KEYS[0]], state[UPDATE_LOG_KEYS[1]] = self.update_log.sums, self.update_log.count
        state[VERDICT_KEY] = self.verdict_counts
        return {k: v.detach().contiguous() for k, v in state.items()}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        learner, method = split_policy_tensors(state)
        self.learner.load_state_dict(learner)
        self.replay.load_state_dict(state)
        world = {k[len("world."):]: v for k, v in state.items() if k.startswith("world.")}
        self.world.state = WorldState(**{k: v.to(self.device) for k, v in world.items()})
        self.layer.reset()
        self.layer.target_lane = state["layer.target_lane"].to(self.device)
        self.stats.load_state_dict({name: state[key] for name, key in EPISODE_KEYS.items() if key in state})
        self.gen.set_state(state["rng.trainer"].cpu() if self.device.type == "cpu" else state["rng.trainer"])
        self.vector_steps = int(state["counters.vector_steps"][0])
        self.step_count.fill_(self.vector_steps)
        self.usage = state["counters.usage"].to(self.device).clone()
        if "counters.update_credit" in state:
            self.update_credit = state["counters.update_credit"].to(self.device, torch.float64).clone()
        if UPDATE_LOG_KEYS[0] in state:  # copied in place: the compiled step holds these tensors
            self.update_log.sums.copy_(state[UPDATE_LOG_KEYS[0]])
            self.update_log.count.copy_(state[UPDATE_LOG_KEYS[1]])
        if VERDICT_KEY in state:  # checkpoints written before the verdicts were counted lack it
            self.verdict_counts = state[VERDICT_KEY].cpu().clone()
        self.method.load_state_dict(method)
        self.method.start(self.batch, self.device, self.static)
        self._view = self.layer.observe(self.world)


def compile_vector_step(trainer: Trainer, how: bool | str, unrolled: bool = False, keep_state: bool | None = None):
    """trainer.vector_step as torch.compile graphs with no break (how: sim.compiled.compile_options), the same
    numbers as the eager static step:

    split (the default): the step up to its updates (Trainer.collect_static), one update round
    (Trainer.static_round, called once per round: the rounds share one graph) and the method's after_step
    where it has one. The code generated is that of one round, whatever the replay ratio: with 16 envs at
    Algorithm 1's rate inductor compiled it in 214 s on the CPU against 443 s for 16 rounds unrolled
    (docs/benchmarks.md).
    unrolled: one graph, the rounds unrolled in it (one graph launch per step; a compile time that grows
    with the rounds). At most two versions of the first graph are compiled (Draws.learn and whether
    Draws.update is None are guarded on).

    Under CUDA graphs a graph's outputs are overwritten by later replays, and a replay writes in place only
    into tensors marked static: every state tensor (world, rule layer, learner, replay, statistics, method)
    is marked so before each call, and one the graph replaced by a new tensor (an output) is copied back
    into the tensor it replaced, so that the state keeps its addresses; the outputs the split step passes
    on are used or copied before the next replay. keep_state: that bookkeeping (None: where CUDA graphs
    replay; the tests run it on the CPU, where it must change nothing)."""
    opts = compile_options(how, trainer.device)
    cuda_graphs = uses_cuda_graphs(opts, trainer.device) if keep_state is None else keep_state
    keeping = state_keeping_call(trainer) if cuda_graphs else (lambda graph, *args: graph(*args))
    # every graph has all its versions once the step learns (Draws.learn never turns False again, and with it
    # whether Draws.update is None is fixed): after WARM_CALLS learning steps, only the guards that tell
    # versions apart are checked (sim.compiled.call_settled)
    learning_steps = 0

    def call(graph, *args):
        return keeping(functools.partial(call_settled, graph) if learning_steps > WARM_CALLS else graph, *args)

    def counted(draws: Draws) -> None:
        nonlocal learning_steps
        learning_steps += bool(draws.learn)

    if unrolled:
        whole = torch.compile(trainer.vector_step, **opts)

        def step_unrolled(draws: Draws) -> None:
            counted(draws)
            call(whole, draws)

        return step_unrolled
    collect = torch.compile(trainer.collect_static, **opts)
    one_round = torch.compile(trainer.static_round, **opts)
    method = trainer.method
    tail = torch.compile(method.after_step, **opts) if type(method).after_step is not Method.after_step else None

    def step(draws: Draws) -> None:
        counted(draws)
        masks, cost, done = call(collect, draws)
        if cuda_graphs:  # the next replay may reuse the outputs' memory: the rounds and the tail read copies
            masks, cost, done = (None if t is None else t.clone() for t in (masks, cost, done))
        for i in range(0 if masks is None else masks.shape[0]):
            call(one_round, draws.update[i], masks[i])
        if tail is not None:
            call(tail, trainer, cost, done)

    return step


def state_keeping_call(trainer: Trainer):
    """call(graph, *args): graph(*args) replayed as a CUDA graph with the trainer's state tensors marked
    static and every state tensor the graph replaced copied back into the one it replaced."""
    # the state's attributes as the trainer starts (an attribute the step adds, such as ET-RL's analysis
    # tensors, is an output the next step does not read)
    names = [[name for name, value in vars(owner).items() if isinstance(value, torch.Tensor)]
             for owner in state_owners(trainer)]

    def call(graph, *args):
        held = [(owner, name, getattr(owner, name)) for owner, keys in zip(state_owners(trainer), names)
                for name in keys]
        for tensor in [t for _, _, t in held] + in_place_state(trainer):
            torch._dynamo.mark_static_address(tensor)
        torch.compiler.cudagraph_mark_step_begin()
        out = graph(*args)
        for owner, name, tensor in held:
            new = getattr(owner, name)
            if new is not tensor:
                tensor.copy_(new)
                setattr(owner, name, tensor)
        return out

    return call


def state_owners(trainer: Trainer) -> list:
    """The objects whose tensor attributes hold the state the vector step carries from one step to the next
    (in place or replaced by new tensors)."""
    layer = trainer.layer
    return [trainer, trainer.learner, trainer.replay, trainer.update_log, trainer.stats, trainer.finished,
            trainer.world.state, trainer.method, layer, getattr(layer, "mapped", layer)]


def in_place_state(trainer: Trainer) -> list[torch.Tensor]:
    """The state tensors held elsewhere than in an attribute, all written in place: weights and replay rows."""
    learner = trainer.learner
    return [learner.online.flat, learner.target.flat, *trainer.replay.storage.values()]
