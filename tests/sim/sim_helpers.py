"""Brute-force references and small drivers shared by the simulator tests."""

from __future__ import annotations

import torch

from highway_srl.sim import World
from highway_srl.sim.box_geometry import boxes_overlap
from highway_srl.sim.ego_driver import idm_ego


def brute_sv_contacts(world: World) -> torch.Tensor:
    """(B,) number of overlapping SV-SV pairs, every pair tested."""
    s = world.state
    x, y, h = s.x[:, 1:], s.y[:, 1:], s.heading[:, 1:]
    over = boxes_overlap(x[:, :, None], y[:, :, None], h[:, :, None], x[:, None, :], y[:, None, :], h[:, None, :])
    m = x.shape[1]
    upper = torch.triu(torch.ones(m, m, dtype=torch.bool, device=x.device), 1)
    return (over & upper).sum((1, 2))


def brute_ego_overlap(world: World) -> torch.Tensor:
    """(B,) bool: the ego's box overlaps some SV's box."""
    s = world.state
    return boxes_overlap(s.x[:, :1], s.y[:, :1], s.heading[:, :1], s.x[:, 1:], s.y[:, 1:], s.heading[:, 1:]).any(1)


def drive(world: World, steps: int, driver=idm_ego, reset: bool = True):
    """Step the world with `driver`, resetting finished envs; yields (t, events) after every step."""
    for t in range(steps):
        lane, speed = driver(world)
        events = world.step(lane, speed)
        yield t, events
        done = events.terminated | events.truncated
        if reset and bool(done.any()):
            world.reset(done)


def keep_lane(speed_mps: float):
    """A driver that holds the ego's lane at a constant commanded speed."""

    def driver(world: World):
        return world.ego_lane, torch.full((world.num_envs,), speed_mps, device=world.device)

    return driver


def clear_road(world: World, speed_mps: float) -> None:
    """Put every SV out of the ego's way: in a queue 60 m and more behind it (inside the window, so that
    recycling leaves them alone), centred in the ego's start lane, cruising at speed_mps (also their
    desired speed), 20 m apart."""
    s = world.state
    m = s.x.shape[1] - 1
    s.x[:, 1:] = s.x[:, :1] - 60.0 - 20.0 * torch.arange(m, device=s.x.device)
    s.y[:, 1:] = s.y[:, :1]
    s.lane[:, 1:] = s.lane[:, :1]
    s.target_lane[:, 1:] = s.lane[:, :1]
    s.heading[:, 1:] = 0.0
    s.v[:, 1:] = speed_mps
    s.v0[:, 1:] = speed_mps
    s.lane_change[:, 1:] = False
    s.intent[:, 1:] = 0  # NO_INTENT
    s.order = torch.sort(s.x, dim=1, stable=True).indices
