"""The paper's baselines (§4.2) and the rule-based driver, as `Method`s (the ablations: agents/ablations.py).

Each one is the few lines that make it different; the trainer, replay, learner, logs and metrics are
shared. docs/paper-notes.md says exactly what each is and which choices the paper leaves open.

  method       view    actions  acting rule                                   training reward
  rl           raw     A (5)    ε-greedy argmax Q                             speed, -320 on collision
  sr-rl        raw     A (5)    highest-Q action that passes the safe check  speed, -320 on collision
  rm-rl        mapped  A* (4)   ε-greedy argmax Q                             r_RM (the paper's)
  mp-rl        mapped  A* (4)   highest-Q action that passes Table 1          speed, -320 on collision
  lm-rl        mapped  A* (4)   argmax Q_r - λ Q_c, λ by dual ascent          speed, -320; cost: u2/u4, collision
  et-rl        mapped  A* (4)   ε-greedy Q; the IDM expert takes over below speed, -320 on collision
                                2 s to collision or 1 s headway (not Table 1)
  rule-based   mapped  A* (4)   IDM + MOBIL-style, first safe action          (logged: r_RM); no learning
  ablations of moe-rm-srl: no_mapping (raw view, A*, nothing gated), no_moe (one DQN, no gate: rm-rl),
  no_rm (speed reward)

"raw" is `rules.raw.RawSafetyLayer` (no ID/rule/action/control mapping), "mapped" is `rules.SafetyLayer`.
"""

from __future__ import annotations

import torch

from highway_srl.agents.dqn import DQNLearner, UpdateStats
from highway_srl.agents.methods import Decision, Method
from highway_srl.constants import DEFAULT_PROFILE
from highway_srl.agents.moe import grouped_q, seed_of_env
from highway_srl.agents.rule_based import rule_based_action, rule_based_decision
from highway_srl.constants import EPISODE_STEPS
from highway_srl.rules import OBS_NAMES, SafetyLayer, choose_second, may_use_second, scenario_reward
from highway_srl.rules.raw import FIVE_ACTIONS, RawSafetyLayer
from highway_srl.rules.reward_machine import U2, U4
from highway_srl.rules.safe_actions import LANE_CHANGE

EGO_VX_COLUMN = OBS_NAMES.index("ego_vx")  # v_x / v_max (every view normalises it the same way)

# LM-RL (docs/paper-notes.md, "LM-RL"): constraint E[Σ_t c_t] <= COST_LIMIT per episode.
COST_LIMIT = 16.0  # 5% of an episode's 320 steps with a safe-distance rule violated
COLLISION_COST = float(EPISODE_STEPS)  # a collision costs as much as violating the rules for a whole episode
LAMBDA_LR = 0.01  # dual step per unit of episode cost above the limit
LAMBDA_INIT = 0.0
LAMBDA_MAX = 100.0

# ET-RL (docs/paper-notes.md, "ET-RL"): the expert takes over below this time to collision, or when a gap is
# shorter than TAKEOVER_GAP_M + TAKEOVER_HEADWAY_S x the speed of the car behind it (the time headway of
# forward-collision warnings: TTC alone never fires at a small gap that is not closing, and an agent that
# accelerates there is back in control one step later, chattering into the leader)
TAKEOVER_TTC_S = 2.0
TAKEOVER_HEADWAY_S = 1.0
TAKEOVER_GAP_M = 2.0


def speed_reward(scenario: str, next_obs: torch.Tensor, events, flags) -> torch.Tensor:
    """The speed/collision reward of RL, SR-RL, MP-RL, LM-RL, ET-RL and w/o RM, (B,): the paper's scenario
    reward (§4.3) with r_RM replaced by v/v_max: two-lane and multi-lane v/v_max; merge 0.7 v/v_max +
    0.3 r_merge; exit 0.5 v/v_max + 0.25 (r_exit,1 + r_exit,2); -320 on collision. At most 320 an episode,
    as the RM reward."""
    speed = next_obs[:, EGO_VX_COLUMN].clamp(0.0, 1.0)
    return scenario_reward(scenario, speed, events.collision, **flags.reward_inputs())


def random_allowed(allowed: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """(B,) long: an action drawn uniformly from the True entries of allowed (B, K) (each row has one), at
    the uniforms u (B, K) in [0, 1): the allowed entry with the largest u."""
    return u.masked_fill(~allowed, -1.0).argmax(1)


def highest_allowed(scores: torch.Tensor, allowed: torch.Tensor) -> torch.Tensor:
    """(B,) long: argmax of scores (B, K) over the allowed (B, K) entries; trying actions in descending
    score order and executing the first allowed one picks exactly this."""
    return scores.masked_fill(~allowed, float("-inf")).argmax(1)


def highest_allowed_value(scores: torch.Tensor, allowed: torch.Tensor) -> torch.Tensor:
    """(B,): the largest score (B, K) among the allowed (B, K) entries."""
    return scores.masked_fill(~allowed, float("-inf")).amax(1)


def dual_update(lam: torch.Tensor, episode_cost: torch.Tensor, limit: float = COST_LIMIT, lr: float = LAMBDA_LR,
                lam_max: float = LAMBDA_MAX) -> torch.Tensor:
    """One projected dual-ascent step on the Lagrange multiplier: λ <- clip(λ + lr (J_c - d), 0, λ_max)."""
    return (lam + lr * (episode_cost - limit)).clamp(0.0, lam_max)


def paired(t: torch.Tensor) -> torch.Tensor:
    """(2K, ...): each row of t (K, ...) twice in a row; for K = 1 a view (no copy)."""
    return t.unsqueeze(1).expand(t.shape[0], 2, *t.shape[1:]).flatten(0, 1)


class _Options:
    """Methods that take no options reject them by name."""

    allowed_options: frozenset[str] = frozenset()

    def _check_options(self) -> None:
        unknown = sorted(k for k, v in self.options.items() if v and k not in self.allowed_options)
        if unknown:
            allowed = ", ".join(sorted(self.allowed_options)) or "none"
            raise ValueError(f"method {self.name!r} does not take option(s) {', '.join(unknown)} (it takes: {allowed}); "
                             "--no-mapping/--no-moe/--no-rm are ablations of moe-rm-srl")


class SingleDQN(_Options, Method):
    """One DQN per seed over the view's action set, ε-greedy; `shielded` restricts both the greedy and the
    random action to the safe set (the safe-action check of Mirchevska et al. 2018)."""

    name = "single-dqn"
    view = "mapped"  # "mapped": SafetyLayer; "raw": RawSafetyLayer
    out_dim = 4
    shielded = False
    reward_kind = "speed"  # "speed": speed_reward; "rm": the paper's r_RM reward
    members_per_seed = 1

    def __init__(self, scenario, seeds, options, profile=DEFAULT_PROFILE):
        super().__init__(scenario, seeds, options, profile)
        self._check_options()
        self.num_members = seeds * self.members_per_seed

    def make_layer(self, road):
        if self.view == "raw":
            return RawSafetyLayer(road, five_actions=self.out_dim == 5, profile=self.profile)
        return SafetyLayer(road, profile=self.profile, **self.layer_options)

    def action_mask(self) -> torch.Tensor:
        return torch.ones(self.num_members, self.out_dim, dtype=torch.bool)

    def safe_mask(self, model) -> torch.Tensor:
        return model.mask5 if self.out_dim == 5 else model.mask

    def allowed(self, model) -> torch.Tensor:
        return self.safe_mask(model) if self.shielded else torch.ones_like(self.safe_mask(model))

    def scores(self, learner: DQNLearner, model) -> torch.Tensor:
        """(B, out_dim) values the greedy action maximises: Q of each env's own seed's network."""
        return grouped_q(learner, model.obs, self.seeds, self.members_per_seed)[:, 0]

    def member(self, batch: int, device) -> torch.Tensor:
        return seed_of_env(batch, self.seeds, device) * self.members_per_seed

    @property
    def draw_width(self) -> int:
        return self.out_dim  # a uniform per action of the view's set (random_allowed)

    def decide(self, learner, step, explore, u) -> Decision:
        use_second = None
        if may_use_second(step):  # multi-lane middle lane: the model whose best action is worth more
            values = [highest_allowed_value(self.scores(learner, m), self.allowed(m)) for m in (step.primary, step.second)]
            use_second = choose_second(values[0], values[1], step.two_models)
        model = step.select(use_second)
        action = self.act(learner, model, explore, u)
        return Decision(action, self.member(action.shape[0], action.device), use_second)

    def act(self, learner, model, explore, u) -> torch.Tensor:
        """explore (B,) bool, u (B, out_dim) uniforms or None (explore all False): see Method.decide."""
        allowed = self.allowed(model)
        greedy = highest_allowed(self.scores(learner, model), allowed)
        return greedy if u is None else torch.where(explore, random_allowed(allowed, u), greedy)

    def reward(self, scenario, nxt, events, flags):
        if self.reward_kind == "rm":
            return super().reward(scenario, nxt, events, flags)
        return speed_reward(scenario, nxt.obs, events, flags), None


class RL(SingleDQN):
    """Standard DQN over A, no reward machine, no shield, no mappings."""

    name, view, out_dim, shielded, reward_kind = "rl", "raw", 5, False, "speed"
    action_names = FIVE_ACTIONS


class SRRL(SingleDQN):
    """Safe-action checking (Mirchevska et al. 2018): the highest-Q action of A that passes the check."""

    name, view, out_dim, shielded, reward_kind = "sr-rl", "raw", 5, True, "speed"
    action_names = FIVE_ACTIONS


class RMRL(SingleDQN):
    """RM-DRL: one DQN over A* trained on the paper's RM reward; no shield."""

    name, view, out_dim, shielded, reward_kind = "rm-rl", "mapped", 4, False, "rm"


class MPRL(SingleDQN):
    """SR-RL with the four mappings: the highest-Q action of A* that Table 1 (on R*_SV) allows."""

    name, view, out_dim, shielded, reward_kind = "mp-rl", "mapped", 4, True, "speed"


def time_to_collision(gap_m: torch.Tensor, closing_mps: torch.Tensor) -> torch.Tensor:
    """Seconds until a bumper gap (any shape, m) closes at closing_mps (> 0: closing); +inf when not closing,
    0 when the gap is already gone."""
    ttc = gap_m.clamp(min=0.0) / closing_mps.clamp(min=1e-6)
    return torch.where(closing_mps > 0, ttc, torch.full_like(ttc, float("inf")))


def takeover_trigger(model, ego_vx: torch.Tensor, proposal: torch.Tensor, ttc_s: float = TAKEOVER_TTC_S,
                     headway_s: float = TAKEOVER_HEADWAY_S) -> torch.Tensor:
    """(B,) bool: ET-RL's danger criterion, independent of Table 1, on the leader in the ego's lane (SV1) and,
    while the agent asks for or continues a lane change, on the target lane's leader (SV2, the ego behind it)
    and follower (SV4, behind the ego): some time to collision is below ttc_s, or some bumper gap is shorter
    than TAKEOVER_GAP_M + headway_s x the speed of the car behind that gap (m, m/s, s; headway_s <= 0: the
    time to collision alone)."""
    gaps, vx = model.gaps_m, model.vehicles.vx
    ttc1 = time_to_collision(gaps[:, 0], ego_vx - vx[:, 0])
    ttc2 = time_to_collision(gaps[:, 1], ego_vx - vx[:, 1])
    ttc4 = time_to_collision(gaps[:, 3], vx[:, 3] - ego_vx)
    ego_behind = ego_vx.clamp(min=0.0)  # the ego is the car behind gaps 1 and 2, SV4 behind gap 4
    short1 = short_headway(gaps[:, 0], ego_behind, headway_s)
    short2 = short_headway(gaps[:, 1], ego_behind, headway_s)
    short4 = short_headway(gaps[:, 3], vx[:, 3].clamp(min=0.0), headway_s)
    changing = (proposal == LANE_CHANGE) | (model.t_id != model.lanes.c_id)
    own = (ttc1 < ttc_s) | short1
    lateral = (torch.minimum(ttc2, ttc4) < ttc_s) | short2 | short4
    return own | (changing & lateral)


def short_headway(gap_m: torch.Tensor, behind_mps: torch.Tensor, headway_s: float) -> torch.Tensor:
    """(B,) bool: a bumper gap shorter than TAKEOVER_GAP_M + headway_s x the speed of the car behind it (m,
    m/s, s); never for headway_s <= 0 (the trigger is then the time to collision alone)."""
    return (gap_m < TAKEOVER_GAP_M + headway_s * behind_mps) & (headway_s > 0)


class ETRL(SingleDQN):
    """Expert takeover (§4.2: "activates a rule-based expert (implemented via the IDM) to override unsafe
    behaviors"): the DQN proposes (ε-greedy over A*) and executes, unless the takeover trigger fires (a time
    to collision below TAKEOVER_TTC_S or a time headway below TAKEOVER_HEADWAY_S, `takeover_trigger`); then
    the rule-based IDM driver's action executes instead, and the DQN learns from what executed. Table 1 is
    not consulted for the trigger: a proposal it forbids runs when nothing is close. Options takeover_ttc_s,
    takeover_headway_s: the thresholds (s)."""

    name, view, out_dim, shielded, reward_kind = "et-rl", "mapped", 4, False, "speed"
    # the layer holds a change under way (the SafetyLayer default); the expert is told so, or it would ask
    # for LaneChange near the boundary, which Eq. 35 turns back into the current lane
    layer_options = {"hold_lane_change": True}
    allowed_options = frozenset({"takeover_ttc_s", "takeover_headway_s"})

    def __init__(self, scenario, seeds, options, profile=DEFAULT_PROFILE):
        super().__init__(scenario, seeds, options, profile)
        self.ttc_s = float(self.options.get("takeover_ttc_s", TAKEOVER_TTC_S))
        self.headway_s = float(self.options.get("takeover_headway_s", TAKEOVER_HEADWAY_S))

    def decide(self, learner, step, explore, u) -> Decision:
        d = super().decide(learner, step, explore, u)
        model = step.select(d.use_second)
        snap = step.snapshot
        ego_v = torch.hypot(snap.ego_vx, snap.ego_vy)
        # (B,) the DQN's proposal and whether the expert overrode it, for analysis and tests
        self.proposal, self.takeover = d.action, takeover_trigger(model, snap.ego_vx, d.action, self.ttc_s,
                                                                      self.headway_s)
        expert = rule_based_action(model, ego_v, self.scenario, self.layer_options["hold_lane_change"])
        return Decision(torch.where(self.takeover, expert, d.action), d.member, d.use_second)


class LMRL(SingleDQN):
    """Lagrangian DQN (constrained RL, Achiam et al. 2017 / Ray et al. 2019 style): per seed a reward
    network Q_r (member 2s) and a cost network Q_c (member 2s + 1) over A*; the policy is
    argmax_a Q_r - λ Q_c; λ >= 0 follows dual ascent on the measured episode cost against COST_LIMIT.

    Cost per step: 1 when the RM state reached is u2 or u4 (a safe-distance rule is violated), COLLISION_COST
    on a collision. Both networks are trained on the same sampled transitions with targets evaluated at the
    policy's next action a' = argmax Q_r - λ Q_c (s') of the target networks (with λ = 0, DQN's max).
    Options: cost_limit, lambda_lr, lambda_init (for experiments; the defaults are the documented values).
    """

    name, view, out_dim, shielded, reward_kind = "lm-rl", "mapped", 4, False, "speed"
    members_per_seed = 2
    uses_cost = True
    allowed_options = frozenset({"cost_limit", "lambda_lr", "lambda_init"})

    def __init__(self, scenario, seeds, options, profile=DEFAULT_PROFILE):
        super().__init__(scenario, seeds, options, profile)
        self.cost_limit = float(self.options.get("cost_limit", COST_LIMIT))
        self.lambda_lr = float(self.options.get("lambda_lr", LAMBDA_LR))
        self.lam = torch.full((seeds,), float(self.options.get("lambda_init", LAMBDA_INIT)))
        self.episode_cost: torch.Tensor | None = None  # (B,) cost of each env's running episode

    def scores(self, learner, model) -> torch.Tensor:
        q = grouped_q(learner, model.obs, self.seeds, self.members_per_seed)  # (B, 2, 4)
        lam = self.lam.to(q.device)[seed_of_env(q.shape[0], self.seeds, q.device)]
        return q[:, 0] - lam[:, None] * q[:, 1]

    def reward(self, scenario, nxt, events, flags):
        reward, _ = super().reward(scenario, nxt, events, flags)
        violated = ((nxt.rm_state == U2) | (nxt.rm_state == U4)).to(reward.dtype)
        cost = torch.where(events.collision, torch.full_like(reward, COLLISION_COST), violated)
        return reward, cost

    def trained_members(self, device) -> torch.Tensor:
        return torch.arange(self.seeds, device=device) * self.members_per_seed  # the reward networks

    def update(self, learner: DQNLearner, members: torch.Tensor, batch: dict,
               mask: torch.Tensor | None = None) -> UpdateStats:
        """members (K,): reward networks (even indices) whose buffers gave batch; their cost networks
        (members + 1) train on the same transitions, toward policy-evaluation targets: the learner's
        td_target at a' = argmax Q_r - λ Q_c of the target networks at s' (passed as the pair's "next_weight"
        (1, -λ)), with the cost as the cost networks' reward.
        mask (K,) bool: only those reward networks and their cost networks step (the static form).
        Returns the reward networks' stats (the logs' Q values are returns, not costs)."""
        # reward and cost network of each seed side by side (2s, 2s + 1, ...): consecutive rows, which the
        # learner reads in place (DQNLearner.update), and each network's row of every input beside its twin's
        both = torch.stack([members, members + 1], 1).flatten().to(learner.device)
        lam = self.lam.to(learner.device)[members.to(learner.device) // self.members_per_seed]
        targets = {"obs": paired(batch["obs"]), "action": paired(batch["action"]),
                   "reward": torch.stack([batch["reward"], batch["cost"]], 1).flatten(0, 1),
                   "next_obs": paired(batch["next_obs"]), "done": paired(batch["done"]),
                   "next_weight": torch.stack([torch.ones_like(lam), -lam], 1)}
        if mask is None:
            return learner.update(both, targets).rows(slice(0, None, 2))
        return learner.update_masked(both, targets, paired(mask)).rows(slice(0, None, 2))

    def start(self, batch, device, static) -> None:
        if static:  # λ on the device and the episode costs from the start (the compact form: λ on the host)
            self.lam = self.lam.to(device)
            if self.episode_cost is None:
                self.episode_cost = torch.zeros(batch, device=device)

    def after_step(self, trainer, cost, done) -> None:
        """Dual ascent: once per vector step in which episodes of a seed ended, λ_seed moves by
        LAMBDA_LR x (mean cost of those episodes - COST_LIMIT)."""
        if self.episode_cost is None or self.episode_cost.shape != cost.shape:
            self.episode_cost = torch.zeros_like(cost)
        self.episode_cost = self.episode_cost.to(cost.device) + cost
        static = getattr(trainer, "static", False)
        if not static and not bool(done.any()):  # the static form computes it anyway: no seed ended, no move
            return
        seed = seed_of_env(cost.shape[0], self.seeds, cost.device)
        ended = done.to(cost.dtype)
        total = torch.zeros(self.seeds, device=cost.device).index_add_(0, seed, self.episode_cost * ended)
        count = torch.zeros(self.seeds, device=cost.device).index_add_(0, seed, ended)
        stepped = dual_update(self.lam.to(cost.device), total / count.clamp(min=1), self.cost_limit, self.lambda_lr)
        self.lam = torch.where(count > 0, stepped, self.lam.to(cost.device))
        if not static:  # the compact form keeps λ on the host; the static one on the device (no copy back)
            self.lam = self.lam.cpu()
        self.episode_cost = torch.where(done, torch.zeros_like(self.episode_cost), self.episode_cost)

    def state_dict(self) -> dict[str, torch.Tensor]:
        state = {"lambda": self.lam.cpu().clone()}
        if self.episode_cost is not None:
            state["episode_cost"] = self.episode_cost.clone()
        return state

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        if "lambda" not in state:
            raise ValueError("lm-rl state has no 'lambda' (the Lagrange multiplier)")
        if state["lambda"].shape != self.lam.shape:
            raise ValueError(f"lm-rl state has λ of shape {tuple(state['lambda'].shape)}, expected {tuple(self.lam.shape)}")
        self.lam = state["lambda"].detach().cpu().clone().float()
        cost = state.get("episode_cost")
        self.episode_cost = None if cost is None else cost.detach().clone().float()


class RuleBased(_Options, Method):
    """IDM + MOBIL-style driver through Table 1 (agents/rule_based.py); nothing is learned: no transition is
    stored and no network is updated (one unused network per seed keeps the run folder's shape).
    Its layer holds the lateral plan (hold_lane_change): with the literal Eq. 34 a lane change cannot be
    completed by any sequence of actions once m*_L = 1 (docs/paper-notes.md, "Lane changes")."""

    name = "rule-based"
    trains = False
    layer_options = {"hold_lane_change": True}

    def __init__(self, scenario, seeds, options, profile=DEFAULT_PROFILE):
        super().__init__(scenario, seeds, options, profile)
        self._check_options()
        self.num_members = seeds

    def action_mask(self) -> torch.Tensor:
        return torch.ones(self.num_members, self.out_dim, dtype=torch.bool)

    def decide(self, learner, step, explore, u) -> Decision:
        action, use_second = rule_based_decision(step, self.scenario, self.layer_options["hold_lane_change"])
        return Decision(action, torch.full_like(action, -1), use_second)

    def store(self, replay, d, obs, reward, next_obs, done, cost, share=False):
        pass

    def updatable(self, acted_count, sizes, batch_size):
        return torch.zeros_like(sizes, dtype=torch.bool)

    def trained_members(self, device):
        return torch.zeros(0, dtype=torch.long, device=device)


class Manual(Method):
    """A person at the keyboard; not trainable here."""

    name = "manual"

    def __init__(self, scenario, seeds, options, profile=DEFAULT_PROFILE):
        raise ValueError(f"method 'manual' is a person at the keyboard: run `highway-srl play --scenario {scenario} "
                         "--traffic C --out FOLDER`; its episodes.jsonl enters the same tables")
