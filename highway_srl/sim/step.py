"""One step of a world's state, in place; how an eager World steps and resets (EAGER); the checks of the
ego's commands.

A step is a fixed sequence of tensor operations over (B, N); there are no per-vehicle objects and no
Python loops over envs or vehicles (only over the at most three lanes).
"""

from __future__ import annotations

import math

import torch

from highway_srl.constants import TrafficLevel
from highway_srl.sim import dynamics
from highway_srl.sim.adversary import cut_ins_whatever_the_gaps
from highway_srl.sim.collisions_and_stages import ego_collision, stage_events
from highway_srl.sim.ego import HOLD_LANE
from highway_srl.sim.events import StepEvents
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.recycle import recycle
from highway_srl.sim.road import Road
from highway_srl.sim.spawn import Layout, spawn
from highway_srl.sim.state import WorldState, astuple_shallow


def step_state(s: WorldState, road: Road, tables: LaneTables, layout: Layout, level: TrafficLevel,
               target_lane: torch.Tensor, target_speed: torch.Tensor, adversary: str | None, max_steps: int,
               static: bool = False) -> StepEvents:
    """One step of every env of s, in place (see World.step); adversary: see World.active_adversary.
    static: static shapes, no host reads (the form torch.compile takes in one graph; sim/selection.py)."""
    if adversary == "paper":
        cut_ins_whatever_the_gaps(s, tables, static)
    sv_collisions, neighbours = dynamics.move_vehicles(s, road, tables, layout, target_lane, target_speed,
                                                       adversary == "mild", static)
    collision = ego_collision(s, road, tables, neighbours, static)
    success, failure = stage_events(s, road)
    recycle(s, road, layout, level, static)
    s.t += 1
    terminated = collision | failure | (success & road.spec.success_terminates)
    truncated = (s.t >= max_steps) & ~terminated
    return StepEvents(collision, success, failure, terminated, truncated, sv_collisions)


def reset_compact(world, mask: torch.Tensor | None) -> None:
    """New episodes (episode + 1) in the envs of world where mask (B,) is True, all envs if None: only
    those envs are spawned, in place (a host read of mask)."""
    s = world.state
    idx = torch.arange(world.num_envs, device=world.device) if mask is None else mask.nonzero().squeeze(1)
    if idx.numel() == 0:
        return
    fresh = spawn(world.road, world.level, world.layout, s.seed[idx], s.episode[idx] + 1, world.style)
    s.index_put(idx, fresh)


class EagerSteps:
    """How an eager World steps (the reference): in this process, operation by operation, in the compact
    form or, with world.static, the static one. CompiledStep (sim/compiled.py) and WorldProcesses
    (sim/processes.py) have the same methods; World chooses one when it is made. Each method takes the
    world it works on, so one EagerSteps serves every eager world and view (EAGER)."""

    compiled, shares_state = False, False

    @property
    def worker_pids(self) -> list[int]:
        return []

    def step(self, world, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        return step_state(world.state, world.road, world.lane_tables, world.layout, world.level, target_lane,
                          target_speed, world.active_adversary, world.max_steps, static=world.static)

    def step_and_reset(self, world, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        events = self.step(world, target_lane, target_speed)
        done = events.terminated | events.truncated
        if bool(done.any()):
            world.reset(done)
        return events

    def reset(self, world, mask: torch.Tensor | None) -> None:
        reset_compact(world, mask)

    def reset_where(self, world, mask: torch.Tensor) -> None:
        fresh = world.spawn_where(world.state, mask)
        torch._foreach_copy_(list(astuple_shallow(world.state)), list(astuple_shallow(fresh)))

    def close(self) -> None:
        pass


EAGER = EagerSteps()


def check_command_types(lane: torch.Tensor, speed: torch.Tensor, num_envs: int) -> None:
    """ValueError unless lane holds integers and speed real numbers, num_envs of each (metadata only: no read
    of the values, so also inside a compiled caller's graph)."""
    if lane.dtype.is_floating_point or lane.dtype.is_complex or lane.dtype == torch.bool:
        raise ValueError(f"target_lane must hold integer lane indices, got dtype {lane.dtype}")
    if speed.dtype.is_complex or speed.dtype == torch.bool:
        raise ValueError(f"target_speed must hold real numbers (m/s), got dtype {speed.dtype}")
    for name, t in (("target_lane", lane), ("target_speed", speed)):
        if t.numel() != num_envs:
            raise ValueError(f"{name} needs {num_envs} value(s), one per env, got shape {tuple(t.shape)}")


def check_command_values(lane: torch.Tensor, speed: torch.Tensor, num_lanes: int) -> None:
    """ValueError unless every lane is one of the road's 0..num_lanes-1 (or HOLD_LANE) and every speed is
    finite and >= 0."""
    lane_lo, lane_hi = (v.item() for v in torch.aminmax(lane))
    if lane_lo < HOLD_LANE or lane_hi >= num_lanes:
        raise ValueError(f"target_lane must be a lane of this road, 0..{num_lanes - 1}, or {HOLD_LANE} (hold the "
                         f"lateral position), got {lane_lo}..{lane_hi}")
    speed_lo, speed_hi = (v.item() for v in torch.aminmax(speed))  # NaN anywhere makes both NaN
    if not (speed_lo >= 0 and math.isfinite(speed_hi)):
        raise ValueError(f"target_speed must be finite and >= 0 m/s, got {speed_lo}..{speed_hi}")
