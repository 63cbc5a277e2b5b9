"""Episode accounting (§4.2): return, deployment reward R_r, collision, average speed and success of B
running episodes, accumulated step by step on the device and read back once per batch of finished ones.

The one place that says how an episode is scored; the trainer, `evaluate`, `play` (and the Gymnasium env
and the backends' episode loop) feed it one step at a time:

    stats = EpisodeStats(world.scenario, world.num_envs, world.device, world.max_steps)
    ... every step:
    events, view, flags = advance(world, layer, action)            # act -> world step -> observe
    stats.add(events, flags, view.primary, world.ego_speed, reward)  # reward: the training reward, or None
    rows = stats.finish(done)                                      # finished envs, one host read; zeroed

Scoring, as in the paper's Tables 5-6:
- R_r sums deployment_step_reward over the episode's steps, minus max_steps (320) on a collision;
- merge: an episode succeeds once the ego has merged (the latched flag), whatever ended it: the success
  event only marks the step of merging;
- success never counts in an episode with a collision;
- the RM return sums the paper's training reward (§4.3: r_RM, or its merge/exit mix, -320 on the collision
  step) computed from the mapped rules, whatever the method trains on: §4.2's T_r on one scale for every
  method, beside each method's own training return.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from highway_srl.rules.metrics import deployment_step_reward
from highway_srl.rules.reward_machine import scenario_reward
from highway_srl.scenarios import scenario_spec
from highway_srl.sim import StageFlags


def advance(world, layer, action: torch.Tensor, use_second: torch.Tensor | None = None):
    """act -> world step -> observe: the action (B,) through the rule layer's control mapping, one world
    step, the layer's view of the new state. Returns (events, view, flags): StepEvents, the layer's step
    (SafetyStep) and the world's latched stage flags after the step."""
    lane, speed = layer.act(action, use_second)
    events = world.step(lane, speed)
    view = layer.observe(world)
    return events, view, world.stage_flags()


RESULT_FIELDS = ("env", "return", "length", "collision", "avg_speed", "success", "deploy_reward", "rm_return")


@dataclass
class EpisodeRow:
    """One finished episode as host numbers."""

    env: int  # index of the env in the batch
    ret: float  # the training return (sum of the rewards passed to add)
    length: int  # steps
    collision: bool
    avg_speed: float  # m/s
    success: bool  # reached the task's goal without a collision (merge, exit)
    deploy_reward: float  # the paper's R_r
    rm_return: float  # the paper's RM training reward summed over the episode (every method alike)


def episode_row(values: list) -> EpisodeRow:
    """An EpisodeRow from one row of EpisodeStats.rows() as host numbers."""
    v = values
    return EpisodeRow(int(v[0]), v[1], int(v[2]), bool(v[3]), v[4], bool(v[5]), v[6], v[7])


OPTIONAL_STATE = ("rm",)  # accumulators added after the first checkpoints were written


class EpisodeStats:
    """Accumulators of B running episodes, (B,) tensors on one device.

    dtype: of the sums; float32 in the batched loops, float64 where one episode is summed on the host's
    terms (play: the same numbers as adding Python floats).
    """

    STATE = ("ret", "deploy", "speed", "length", "collision", "success", "rm")

    def __init__(self, scenario: str, num_envs: int, device: torch.device | str, max_steps: int,
                 dtype: torch.dtype = torch.float32):
        self.scenario, self.max_steps = scenario, max_steps
        self.success_flag = scenario_spec(scenario).success_flag
        z = lambda dt=dtype: torch.zeros(num_envs, dtype=dt, device=device)  # noqa: E731
        self.ret, self.deploy, self.speed, self.rm = z(), z(), z(), z()
        self.length = z(torch.long)
        self.collision, self.success = z(torch.bool), z(torch.bool)

    def add(self, events, flags: StageFlags, view, ego_speed: torch.Tensor, reward: torch.Tensor | None = None,
            alive: torch.Tensor | None = None) -> None:
        """Account one step of every env: events (StepEvents), flags (the world's latched stage flags after
        the step), view (the rule layer's primary model step after the step: speed_ratio, r_star),
        ego_speed (B,) m/s, reward (B,) the training reward or None; alive (B,) bool: only these envs
        count this step (None: all)."""
        deploy = deployment_step_reward(self.scenario, view.speed_ratio, r_star=view.r_star, **flags.reward_inputs())
        rm = scenario_reward(self.scenario, view.scoring_r_rm(), events.collision, **flags.reward_inputs())
        success = events.success if self.success_flag is None else events.success | getattr(flags, self.success_flag)
        collision = events.collision
        if alive is None:
            if reward is not None:
                self.ret += reward
            self.deploy += deploy
            self.rm += rm
            self.speed += ego_speed
            self.length += 1
        else:
            if reward is not None:
                self.ret += torch.where(alive, reward, 0.0)
            self.deploy += torch.where(alive, deploy, 0.0)
            self.rm += torch.where(alive, rm, 0.0)
            self.speed += torch.where(alive, ego_speed, 0.0)
            self.length += alive.long()
            collision, success = alive & collision, alive & success
        self.collision |= collision
        self.success |= success

    def results(self) -> dict[str, torch.Tensor]:
        """The scores of every env's episode so far, (B,) tensors on the device (RESULT_FIELDS but env)."""
        collided = self.collision
        return {
            "return": self.ret,
            "length": self.length,
            "collision": collided,
            "avg_speed": self.speed / self.length.clamp(min=1).to(self.speed.dtype),
            "success": self.success & ~collided,
            "deploy_reward": self.deploy - float(self.max_steps) * collided.to(self.deploy.dtype),
            "rm_return": self.rm,
        }

    def rows(self) -> torch.Tensor:
        """(B, len(RESULT_FIELDS)) in the sums' dtype: every env's row of results so far, env index first."""
        r = self.results()
        env = torch.arange(self.ret.shape[0], device=self.ret.device)
        return torch.stack([env.to(self.ret.dtype)] + [r[k].to(self.ret.dtype) for k in RESULT_FIELDS[1:]], 1)

    def finish(self, done: torch.Tensor) -> list[EpisodeRow]:
        """Rows of the envs where done (B,) is True, read with one host read; their accumulators restart."""
        idx = done.nonzero().squeeze(1)
        out = [episode_row(v) for v in self.rows()[idx].cpu().tolist()]
        for name in self.STATE:
            getattr(self, name)[idx] = 0
        return out

    def restart(self, done: torch.Tensor) -> None:
        """Zero the accumulators of the envs where done (B,) is True: static shapes, no host read."""
        for name in self.STATE:
            getattr(self, name).masked_fill_(done, 0)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {name: getattr(self, name) for name in self.STATE}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """A state saved before the RM return existed ("rm" missing) restarts that sum at 0 for the running
        episodes (their RM return then counts only the steps after the resume)."""
        for name in self.STATE:
            old = getattr(self, name)
            if name not in state and name in OPTIONAL_STATE:
                continue
            setattr(self, name, state[name].to(device=old.device, dtype=old.dtype).clone())


class FinishedEpisodes:
    """Finished episodes kept on the device until the host reads them (drain): recording is static-shape
    and reads nothing back, so a training loop reads its episodes once every few vector steps.

    Rows go in the order they finished (vector step, then env), as finish() would have returned them.
    capacity: rows held between two drains; an env ends at most one episode per vector step, so B x K
    rows hold K vector steps. tag: a long per row (the trainer's vector step)."""

    def __init__(self, capacity: int, width: int, device: torch.device | str, dtype: torch.dtype = torch.float32):
        self.capacity = capacity
        # + one scratch row that the envs which did not finish write to (no boolean indexing)
        self.values = torch.zeros(capacity + 1, width, dtype=dtype, device=device)
        self.tags = torch.zeros(capacity + 1, dtype=torch.long, device=device)
        self.count = torch.zeros((), dtype=torch.long, device=device)  # rows held (a device number)

    def record(self, done: torch.Tensor, rows: torch.Tensor, tag: torch.Tensor) -> None:
        """Append rows (B, width) of the envs where done (B,) is True, each tagged with tag (a long tensor
        on the device: a Python number would be a host-to-device copy, which waits for the device)."""
        rank = done.long().cumsum(0) - 1
        pos = torch.where(done, (self.count + rank).clamp(max=self.capacity), self.capacity)
        self.values.index_put_((pos,), rows.to(self.values.dtype))
        self.tags.index_put_((pos,), tag.expand_as(pos))
        self.count += done.long().sum()

    def drain(self) -> tuple[list[list], list[int]]:
        """(rows, tags) as host lists, in the order recorded (one host read); the buffer empties."""
        n = int(self.count)
        if n > self.capacity:
            raise RuntimeError(f"{n} finished episodes overflowed a buffer of {self.capacity}: drain more often")
        values, tags = self.values[:n].cpu().tolist(), self.tags[:n].cpu().tolist()
        self.count.zero_()
        return values, tags
