"""The road's lanes as tensors on the simulation's device: where each lane exists, where dropped lanes end,
and the lane-change windows; the allowed-change test every driver and the ego controller use."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from highway_srl.constants import VEHICLE_LENGTH_M
from highway_srl.sim.road import Road


@dataclass(frozen=True)
class LaneTables:
    start_m: torch.Tensor  # (K,)
    end_m: torch.Tensor  # (K,)
    drop_end_m: torch.Tensor  # (K,) x where a dropped lane ends, inf otherwise
    window_lo: torch.Tensor  # (K-1,) lane-change window per boundary
    window_hi: torch.Tensor
    drop_end: tuple[float, ...]  # drop_end_m on the host, so the step never reads it back from a GPU
    lane_width_m: float
    # every lane everywhere and every boundary open everywhere (two-lane, multi-lane): can_change then
    # only checks adjacency (known on the host; the other tests would hold for every finite x)
    unbounded: bool = False

    @staticmethod
    def of(road: Road, device) -> "LaneTables":
        t = lambda v: torch.tensor(v, dtype=torch.float32, device=device)  # noqa: E731
        drop = [e if d else math.inf for e, d in zip(road.lane_end_m, road.lane_drop)]
        unbounded = (all(v == -math.inf for v in road.lane_start_m) and all(v == math.inf for v in road.lane_end_m)
                     and all(w == (-math.inf, math.inf) for w in road.change_window_m))
        return LaneTables(
            t(road.lane_start_m),
            t(road.lane_end_m),
            t(drop),
            t([w[0] for w in road.change_window_m]),
            t([w[1] for w in road.change_window_m]),
            tuple(drop),
            road.lane_width_m,
            unbounded,
        )

    def can_change(self, x: torch.Tensor, lane: torch.Tensor, to: torch.Tensor, ahead_m=0.0) -> torch.Tensor:
        """Moving from lane to the adjacent lane `to` is allowed at x and still at x + ahead_m (all (B, N)
        or (B,); ahead_m: a float or a tensor like x, the distance the change will take)."""
        k = self.start_m.shape[0]
        ok = ((to - lane).abs() == 1) & (to >= 0) & (to < k)
        if self.unbounded:
            return ok
        toc = to.clamp(0, k - 1)
        x_end = x + ahead_m
        # torch.take: a lookup in a small table, without advanced indexing's general path
        ok &= (self.start_m.take(toc) <= x) & (x_end + 0.5 * VEHICLE_LENGTH_M < self.end_m.take(toc))
        b = torch.minimum(lane, toc).clamp(0, k - 2)
        return ok & (self.window_lo.take(b) <= x) & (x_end < self.window_hi.take(b))

