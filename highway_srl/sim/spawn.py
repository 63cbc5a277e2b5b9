"""Initial placement of the ego and the surrounding vehicles (Tables 3 and 4).

Vehicles form queues in each lane around the ego, ahead and behind alternately, with bumper-to-bumper
headways drawn from the level's range: a closed-loop flow centred on the ego (§4.1). The layout of who
goes where is static per (scenario, level) and computed once on the host; only the draws are batched.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import torch

from highway_srl.constants import (
    ADVERSARIAL_TRIGGER_OFFSETS_M,
    STYLES,
    SV_INIT_SPEED_MPS,
    V_MAX_MPS,
    VEHICLE_LENGTH_M,
    TrafficLevel,
)
from highway_srl.sim import rng
from highway_srl.sim.idm_mobil import sorted_order
from highway_srl.sim.road import Road
from highway_srl.sim.state import EXIT_INTENT, MERGE_INTENT, NO_INTENT, WorldState

EXIT_INTENT_PROB = 0.25  # share of mainline vehicles that take the off-ramp in the exit scenario
S_EGO_LANE, S_LANE_PHASE, S_SPEED, S_HEADWAY, S_STYLE, S_INTENT, S_OFFSET, S_PHASE = range(8)


@dataclass(frozen=True)
class Layout:
    """Static slot of each surrounding vehicle: which queue (lane, side) and its rank there."""

    lane: torch.Tensor  # (M,) long; M = number of SVs
    side: torch.Tensor  # (M,) +1 ahead, -1 behind
    slot: torch.Tensor  # (M,) long, queue * max_rank + rank: where the SV sits in a (queues, max_rank) grid
    num_queues: int
    max_rank: int
    ramp: torch.Tensor  # (M,) bool, starts on the ramp lane
    window_m: float  # half-length of the region kept populated around the ego
    margin_m: float  # hysteresis before a vehicle is recycled


def make_layout(road: Road, level: TrafficLevel, num_vehicles: int) -> Layout:
    m = num_vehicles
    lanes, ramp = [], []
    n_ramp = max(1, m // 8) if road.spec.svs_start_on_ramp else 0
    for j in range(m):
        if j < n_ramp:
            lanes.append(2)
            ramp.append(True)
        else:
            lanes.append((j - n_ramp) % road.mainline_lanes)
            ramp.append(False)
    # queue position: alternate ahead / behind within each lane; ramp vehicles mostly behind the ego's start
    side, rank, count = [], [], {}
    for j, lane in enumerate(lanes):
        c = count.get(lane, 0)
        count[lane] = c + 1
        s = (1 if c % 2 == 0 else -1) if not ramp[j] else (1 if c == 0 else -1)
        side.append(s)
        rank.append(sum(1 for i in range(j) if lanes[i] == lane and side[i] == s))
    queues = sorted({(lane, s) for lane, s in zip(lanes, side)})
    max_rank = max(rank) + 1
    slot = [queues.index((lane, s)) * max_rank + r for lane, s, r in zip(lanes, side, rank)]
    per_lane = math.ceil((m - n_ramp) / road.mainline_lanes)
    mean_spacing = VEHICLE_LENGTH_M + 0.5 * sum(level.headway_m)
    window = max(math.ceil(per_lane / 2) * mean_spacing + 0.5 * mean_spacing, 60.0)
    return Layout(
        lane=torch.tensor(lanes),
        side=torch.tensor(side, dtype=torch.float32),
        slot=torch.tensor(slot),
        num_queues=len(queues),
        max_rank=max_rank,
        ramp=torch.tensor(ramp),
        window_m=window,
        margin_m=VEHICLE_LENGTH_M + level.headway_m[1],
    )


@dataclass(frozen=True)
class _Constants:
    """What every spawn of one layout reads, on one device: built once (a spawn runs for the few envs that
    reset in a step, so building these tensors from Python lists each time was a good part of its cost)."""

    lane: torch.Tensor  # (M,) the layout's lanes
    side: torch.Tensor  # (M,)
    slot: torch.Tensor  # (M,)
    queue: torch.Tensor  # (M,) the queue of each slot (slot // max_rank)
    ramp: torch.Tensor  # (M,)
    index: torch.Tensor  # (N,) 0..N-1
    styles: torch.Tensor  # (4, styles) float32: SVR, DH, ALC (0 / 1), ABP of each style
    offsets: torch.Tensor  # the adversarial trigger offsets


@functools.lru_cache(maxsize=64)
def _constants(layout: Layout, dev: torch.device) -> _Constants:
    table = [[float(getattr(s, a)) for s in STYLES]
             for a in ("speed_violation", "desired_headway_m", "lane_change", "adversarial_prob")]
    return _Constants(
        lane=layout.lane.to(dev), side=layout.side.to(dev), slot=layout.slot.to(dev),
        queue=(layout.slot // layout.max_rank).to(dev), ramp=layout.ramp.to(dev),
        index=torch.arange(layout.lane.shape[0] + 1, device=dev),
        styles=torch.tensor(table, dtype=torch.float32, device=dev),
        offsets=torch.tensor(ADVERSARIAL_TRIGGER_OFFSETS_M, device=dev),
    )


@functools.lru_cache(maxsize=64)
def _start_lanes(lanes: tuple[int, ...], dev: torch.device) -> torch.Tensor:
    return torch.tensor(lanes, device=dev)


def _sv_x(road: Road, level: TrafficLevel, layout: Layout, u: list[torch.Tensor], ego_x: torch.Tensor,
          ego_lane: torch.Tensor) -> torch.Tensor:
    """(B, M) m: the SVs' positions, queued ahead of and behind the ego in each lane with drawn headways."""
    dev = ego_x.device
    b, m = ego_x.shape[0], layout.lane.shape[0]
    c = _constants(layout, dev)
    h_lo, h_hi = level.headway_m
    spacing = VEHICLE_LENGTH_M + h_lo + (h_hi - h_lo) * u[S_HEADWAY]  # (B, M)
    # distance from the ego along the queue: a running sum per queue (cumsum, not a matrix product, so that
    # an env's numbers do not depend on how many envs share the batch)
    grid = torch.zeros(b, layout.num_queues * layout.max_rank, device=dev).index_copy_(1, c.slot, spacing)
    grid = grid.view(b, layout.num_queues, layout.max_rank)
    offset = grid.cumsum(2).view(b, -1).index_select(1, c.slot)
    first_spacing = grid[:, :, 0].index_select(1, c.queue)  # the first spacing of each SV's queue
    # lanes other than the ego's get a random phase so their queues do not line up with the ego's
    phase = u[S_LANE_PHASE]  # (B, lanes)
    sv_lane = c.lane.expand(b, m)
    in_ego_lane = sv_lane == ego_lane[:, None]
    lane_phase = torch.gather(phase, 1, sv_lane)
    side = c.side
    shift = torch.where(side > 0, (1 - lane_phase) * first_spacing, lane_phase * first_spacing)
    shift = torch.where(in_ego_lane | c.ramp, torch.zeros_like(shift), shift)
    return ego_x[:, None] + side * (offset - shift)


def _styles(u: list[torch.Tensor], style: int | None, b: int, m: int, dev) -> torch.Tensor:
    """(B, N) long: each vehicle's index into STYLES, the ego's 0; drawn unless one `style` is given."""
    if style is None:
        sv_style = rng.to_int(u[S_STYLE], len(STYLES))
    else:
        sv_style = torch.full((b, m), style, dtype=torch.long, device=dev)
    return torch.cat([torch.zeros(b, 1, dtype=torch.long, device=dev), sv_style], 1)


def _intents(road: Road, layout: Layout, u: list[torch.Tensor], b: int, m: int, dev) -> torch.Tensor:
    """(B, N) long: ramp SVs merge; in the exit scenario a drawn share of the mainline SVs exit."""
    intent = torch.full((b, m + 1), NO_INTENT, dtype=torch.long, device=dev)
    if road.spec.svs_start_on_ramp:
        intent[:, 1:] = torch.where(_constants(layout, dev).ramp, MERGE_INTENT, NO_INTENT).expand(b, m)
    elif road.spec.svs_may_exit:
        exits = u[S_INTENT] < EXIT_INTENT_PROB
        intent[:, 1:] = torch.where(exits, EXIT_INTENT, NO_INTENT)
    return intent


def spawn(
    road: Road,
    level: TrafficLevel,
    layout: Layout,
    seed: torch.Tensor,
    episode: torch.Tensor,
    style: int | None,
) -> WorldState:
    """Fresh episodes for envs with these seeds and episode numbers (each (B,) long)."""
    dev = seed.device
    b, m = seed.shape[0], layout.lane.shape[0]
    n = m + 1
    width = {S_EGO_LANE: None, S_LANE_PHASE: road.num_lanes, S_SPEED: n, S_HEADWAY: m, S_STYLE: m, S_INTENT: m,
             S_OFFSET: n, S_PHASE: None}  # None: one draw per env
    u = rng.uniforms(rng.episode_key(seed, episode), 0, tuple(width[s] for s in range(len(width))))

    c = _constants(layout, dev)
    starts = _start_lanes(road.ego_start_lanes, dev)
    ego_lane = starts[rng.to_int(u[S_EGO_LANE], len(road.ego_start_lanes))]
    ego_x = torch.full((b,), road.ego_start_x_m, device=dev)
    lo, hi = SV_INIT_SPEED_MPS
    speed = lo + (hi - lo) * u[S_SPEED]  # (B, N), column 0 for the ego
    x = torch.cat([ego_x[:, None], _sv_x(road, level, layout, u, ego_x, ego_lane)], 1)
    lane = torch.cat([ego_lane[:, None], c.lane.expand(b, m)], 1)
    y = lane.to(torch.float32) * road.lane_width_m

    sty = _styles(u, style, b, m, dev)
    violation, headway, lane_change, adversarial_prob = c.styles[:, sty]  # (B, N) each, one lookup
    v0 = (1.0 + violation) * V_MAX_MPS
    v0[:, 0] = V_MAX_MPS
    offsets = c.offsets
    zeros_b = torch.zeros(b, n, dtype=torch.bool, device=dev)
    return WorldState(
        x=x,
        y=y,
        v=speed,
        heading=torch.zeros(b, n, device=dev),
        lane=lane,
        target_lane=lane.clone(),
        style=sty,
        v0=v0,
        s0=headway,
        lane_change=lane_change.bool(),
        adversarial_prob=adversarial_prob,
        intent=_intents(road, layout, u, b, m, dev),
        trigger_offset=offsets[rng.to_int(u[S_OFFSET], len(offsets))],
        trigger_used=zeros_b.clone(),
        forced=zeros_b.clone(),
        # vehicle n decides at steps t with (t + phase) % 8 == 0; the per-episode offset is drawn, the
        # stride by index spreads the decisions (see dynamics.decision_slots)
        phase=(rng.to_int(u[S_PHASE], 8)[:, None] + c.index) % 8,
        order=sorted_order(x),
        seed=seed.clone(),
        episode=episode.clone(),
        t=torch.zeros(b, dtype=torch.long, device=dev),
        merged=torch.zeros(b, dtype=torch.bool, device=dev),
        exit1=ego_lane == 1,
        exit2=ego_lane == 2,
    )
