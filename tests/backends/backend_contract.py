"""Behaviour every one-env backend must show, written once and run against each (SUMO, highway-env, ours).

A `make(**kwargs)` argument builds a backend: make(scenario=..., traffic=..., adversarial=..., seed=...,
plus style / num_vehicles); each check drives it and asserts.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from highway_srl.backends.bookkeeping import EpisodeCore
from highway_srl.constants import D_MAX_M, V_MAX_MPS, VEHICLE_LENGTH_M
from highway_srl.sim.ego_driver import idm_ego_backend
from highway_srl.sim.snapshot import LANE_END, NO_VEHICLE


def _frame_arrays(backend):
    """(x, lane, present) of every vehicle in our frame, vehicle 0 = ego (World: its state)."""
    if hasattr(backend, "frame"):
        f = backend.frame
        return f.x.copy(), f.lane.copy(), f.present.copy()
    s = backend.state
    return s.x[0].numpy().astype(float), s.lane[0].numpy(), np.ones(s.x.shape[1], bool)


def check_snapshot_invariants(make, scenario: str, steps: int, traffic: str = "D", seed: int = 0) -> set:
    """Every step: SV1..SV4 are the nearest vehicles ahead / behind in the queried lanes within d_max (by
    centre x, lane by nearest centre), lanes are in range, numbers are finite. Returns the sv_index values
    seen (to let a caller check that lane ends appeared)."""
    b = make(scenario=scenario, traffic=traffic, adversarial=True, seed=seed)
    k_lanes = b.road.num_lanes
    seen = set()
    for t in range(steps):
        lane = b.ego_lane
        assert lane.shape == (1,) and 0 <= int(lane[0]) < k_lanes
        adj = int(lane[0]) + (1 if t % 2 == 0 else -1)
        adj = adj if 0 <= adj < k_lanes else -1
        snap = b.neighbours(lane, torch.tensor([adj]))
        x, lanes, present = _frame_arrays(b)
        ego_x = float(snap.ego_x[0])
        assert math.isclose(ego_x, float(x[0]), abs_tol=1e-3)
        for name in ("ego_x", "ego_y", "ego_vx", "ego_vy", "ego_heading", "sv_x", "sv_y", "sv_vx", "sv_vy", "sv_heading"):
            assert torch.isfinite(getattr(snap, name)).all(), name
        assert 0 <= int(snap.ego_lane[0]) < k_lanes
        for slot, (query, front) in enumerate(((int(lane[0]), True), (adj, True), (int(lane[0]), False), (adj, False))):
            idx, valid = int(snap.sv_index[0, slot]), bool(snap.sv_valid[0, slot])
            seen.add(idx)
            dx = x[1:] - ego_x
            cand = present[1:] & (lanes[1:] == query) & (np.abs(dx) <= D_MAX_M) & ((dx > 0) if front else (dx <= 0))
            if query < 0:
                assert not valid and idx == NO_VEHICLE
                continue
            if idx == LANE_END:
                assert front and b.road.lane_drop[query]
                wall = b.road.lane_end_m[query] + 0.5 * VEHICLE_LENGTH_M
                assert math.isclose(float(snap.sv_x[0, slot]), wall, abs_tol=1e-3)
                assert float(snap.sv_vx[0, slot]) == 0.0
                assert not cand.any() or np.min(dx[cand]) >= wall - ego_x - 1e-3
                continue
            if not cand.any():
                assert not valid and idx == NO_VEHICLE, (t, slot)
                continue
            assert valid, (t, slot)
            assert 1 <= idx < len(x) and lanes[idx] == query and present[idx]
            best = np.min(np.abs(dx[cand]))
            assert math.isclose(abs(x[idx] - ego_x), best, abs_tol=1e-3), (t, slot, idx)
            assert math.isclose(float(snap.sv_x[0, slot]), float(x[idx]), abs_tol=1e-2)
            assert math.isclose(float(snap.sv_y[0, slot]) / b.road.lane_width_m, query, abs_tol=0.5 + 1e-6)
        ev = b.step(*idm_ego_backend(b))
        if bool(ev.terminated[0] | ev.truncated[0]):
            b.reset()
    return seen


def seed_with_sv_ahead_in_ego_lane(scenario: str = "two-lane") -> int:
    """A seed whose episode 0 puts the one SV of a one-SV world ahead in the ego's lane."""
    for seed in range(100):
        core = EpisodeCore(scenario, "C", False, seed, style="normal", num_vehicles=1)
        x, lane = core.initial["x"], core.initial["lane"]
        if lane[1] == lane[0] and x[1] > x[0]:
            return seed
    raise AssertionError("no such seed in 0..99")


def check_rear_end_collision(make, max_steps: int = 160) -> int:
    """Straight on at the speed limit behind a slower car (normal style: 7 m/s): a collision is reported,
    with that car as SV1 closing in until then. Returns the step of the collision."""
    seed = seed_with_sv_ahead_in_ego_lane()
    b = make(scenario="two-lane", traffic="C", adversarial=False, seed=seed, style="normal", num_vehicles=1)
    lane = b.ego_lane.clone()
    last_gap = float("inf")
    for t in range(max_steps):
        snap = b.neighbours(lane, torch.tensor([-1]))
        assert int(snap.sv_index[0, 0]) == 1, "the slower car is SV1"
        gap = float(snap.sv_x[0, 0] - snap.ego_x[0]) - VEHICLE_LENGTH_M
        assert gap <= last_gap + 1e-3, "the gap closes"
        last_gap = gap
        ev = b.step(lane, torch.tensor([V_MAX_MPS]))
        assert int(b.ego_lane[0]) == int(lane[0]), "straight on"
        if bool(ev.collision[0]):
            assert bool(ev.terminated[0]) and not bool(ev.truncated[0])
            assert last_gap < 2.0
            return t
    raise AssertionError(f"no collision reported in {max_steps} steps (last gap {last_gap:.2f} m)")


def _trajectory(b, steps: int) -> np.ndarray:
    rows = []
    for _ in range(steps):
        lane, speed = idm_ego_backend(b)
        ev = b.step(lane, speed)
        snap = b.neighbours(b.ego_lane, torch.tensor([-1]))
        rows.append([float(snap.ego_x[0]), float(snap.ego_y[0]), float(b.ego_speed[0]),
                     *snap.sv_x[0].tolist(), *snap.sv_index[0].tolist(), float(ev.collision[0])])
    return np.array(rows)


def check_seeded_episode_reproduces(make, scenario: str = "merge", steps: int = 60, seed: int = 5) -> None:
    """Episode 0 of a seed, replayed after other episodes and on a fresh backend, is the same."""
    b = make(scenario=scenario, traffic="C", adversarial=True, seed=seed)
    first = _trajectory(b, steps)
    b.reset()  # episode 1
    other = _trajectory(b, steps // 2)
    b.reset(episode=0)
    again = _trajectory(b, steps)
    np.testing.assert_allclose(again, first, atol=1e-4)
    assert not np.allclose(other, first[: len(other)], atol=1e-4), "episode 1 differs from episode 0"
    if hasattr(b, "close"):
        b.close()
    fresh = _trajectory(make(scenario=scenario, traffic="C", adversarial=True, seed=seed), steps)
    np.testing.assert_allclose(fresh, first, atol=1e-4)


def check_merge_episode_succeeds(make, seed: int = 1, traffic: str = "A") -> int:
    """The backend-agnostic IDM / gap-check driver merges from the on-ramp: a success event, no collision."""
    b = make(scenario="merge", traffic=traffic, adversarial=False, seed=seed)
    assert int(b.ego_lane[0]) == 2, "the ego starts on the on-ramp"
    for t in range(b.max_steps):
        ev = b.step(*idm_ego_backend(b))
        assert not bool(ev.collision[0]), f"collision at step {t}"
        if bool(ev.success[0]):
            assert bool(b.stage_flags().merged[0]) and int(b.ego_lane[0]) < 2
            return t
    raise AssertionError("no success within the episode")


def check_ramp_end(make, tolerance_m: float = 1e-3) -> None:
    """An ego that stays on the on-ramp sees its end as a standing obstacle (LANE_END, rear at x2) and
    running into it is a collision (its front bumper at the lane end), not an error; stepping on is allowed."""
    b = make(scenario="merge", traffic="A", seed=1)
    x2 = b.road.lane_end_m[2]
    seen_wall = False
    for _ in range(300):
        snap = b.neighbours(torch.tensor([2]), torch.tensor([1]))
        if int(snap.sv_index[0, 0]) == LANE_END:
            seen_wall = True
            assert math.isclose(float(snap.sv_x[0, 0]), x2 + 0.5 * VEHICLE_LENGTH_M, abs_tol=1e-3)
        ev = b.step(torch.tensor([2]), torch.tensor([8.0]))
        if bool(ev.terminated[0]):
            break
    assert seen_wall
    assert bool(ev.collision[0])
    assert float(b.neighbours(b.ego_lane, torch.tensor([-1])).ego_x[0]) + 0.5 * VEHICLE_LENGTH_M >= x2 - tolerance_m
    ev = b.step(torch.tensor([2]), torch.tensor([8.0]))
    assert bool(ev.terminated[0] | ev.truncated[0])
