"""Oriented-box collision (separating-axis test) and the drivable corridor check."""

from __future__ import annotations

import math

import torch

from highway_srl.constants import VEHICLE_LENGTH_M, VEHICLE_WIDTH_M

# Two L x B boxes can only overlap if their centres are closer than twice the half-diagonal, so
# |dx| and |dy| below this are a cheap necessary condition checked before the exact test.
CONTACT_REACH_M = math.hypot(VEHICLE_LENGTH_M, VEHICLE_WIDTH_M) + 1e-3
# the bumper gap below which a pair may touch within a step (two L x B boxes touch only with centres
# closer than CONTACT_REACH_M; a car gains at most v dt < 2 m on its leader per step at SV speeds <= 13 m/s)
CONTACT_GAP_M = CONTACT_REACH_M - VEHICLE_LENGTH_M + 2.5


def boxes_overlap(
    xa: torch.Tensor,
    ya: torch.Tensor,
    ha: torch.Tensor,
    xb: torch.Tensor,
    yb: torch.Tensor,
    hb: torch.Tensor,
    length_m: float = VEHICLE_LENGTH_M,
    width_m: float = VEHICLE_WIDTH_M,
) -> torch.Tensor:
    """True where rectangle A (centre xa, ya, heading ha) overlaps rectangle B; all args broadcast.

    Two convex shapes are disjoint iff some edge normal separates their projections; for two rectangles
    the candidate normals are the two axes of each box.
    """
    hl, hw = 0.5 * length_m, 0.5 * width_m
    ca, sa, cb, sb = torch.cos(ha), torch.sin(ha), torch.cos(hb), torch.sin(hb)
    dx, dy = xb - xa, yb - ya
    # On its own axes a box projects to hl or hw; on the other box's axes to hl|c| + hw|s| or hl|s| + hw|c|
    # with c, s = cos, sin of the heading difference. So both long axes share one radius sum, both short
    # axes another.
    c, s = (ca * cb + sa * sb).abs(), (sa * cb - ca * sb).abs()
    r_long, r_short = hl + hl * c + hw * s, hw + hl * s + hw * c
    overlap = (dx * ca + dy * sa).abs() <= r_long
    overlap &= (dy * ca - dx * sa).abs() <= r_short
    overlap &= (dx * cb + dy * sb).abs() <= r_long
    overlap &= (dy * cb - dx * sb).abs() <= r_short
    return overlap


def boxes_separation(xa, ya, ha, xb, yb, hb, length_m: float = VEHICLE_LENGTH_M,
                     width_m: float = VEHICLE_WIDTH_M) -> torch.Tensor:
    """The largest gap between the projections of rectangles A and B on the four axes of boxes_overlap (m;
    all args broadcast): > 0 where they are apart, by at most their distance (a projection shortens no
    distance), exactly it where a side of one box faces the other's nearest point; <= 0 where they overlap."""
    hl, hw = 0.5 * length_m, 0.5 * width_m
    ca, sa, cb, sb = torch.cos(ha), torch.sin(ha), torch.cos(hb), torch.sin(hb)
    dx, dy = xb - xa, yb - ya
    c, s = (ca * cb + sa * sb).abs(), (sa * cb - ca * sb).abs()
    r_long, r_short = hl + hl * c + hw * s, hw + hl * s + hw * c
    gap = torch.maximum((dx * ca + dy * sa).abs() - r_long, (dy * ca - dx * sa).abs() - r_short)
    gap = torch.maximum(gap, (dx * cb + dy * sb).abs() - r_long)
    return torch.maximum(gap, (dy * cb - dx * sb).abs() - r_short)


def lateral_half_extent(heading: torch.Tensor, length_m: float = VEHICLE_LENGTH_M, width_m: float = VEHICLE_WIDTH_M):
    """Half of a rotated box's extent along y (m)."""
    return 0.5 * width_m * torch.cos(heading).abs() + 0.5 * length_m * torch.sin(heading).abs()


def front_x_in_band(
    x: torch.Tensor,
    y: torch.Tensor,
    heading: torch.Tensor,
    y_lo: float,
    y_hi: float,
    length_m: float = VEHICLE_LENGTH_M,
    width_m: float = VEHICLE_WIDTH_M,
) -> torch.Tensor:
    """Largest x of the part of each box that lies in the band y_lo <= y <= y_hi; -inf where none does.

    That part is a convex polygon whose vertices are the box's corners inside the band and the points
    where its edges cross the band's lines, so the maximum over those points is exact. It tells when a car
    that is leaving a lane reaches the lane's end: only the part of it still in that lane can hit the end.
    """
    hl, hw = 0.5 * length_m, 0.5 * width_m
    c, s = torch.cos(heading), torch.sin(heading)
    corners = [(x + a * c - b * s, y + a * s + b * c) for a, b in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))]
    ninf = torch.full_like(x, -math.inf)
    best = ninf
    for cx, cy in corners:
        best = torch.maximum(best, torch.where((cy >= y_lo) & (cy <= y_hi), cx, ninf))
    for i in range(4):
        (px, py), (qx, qy) = corners[i], corners[(i + 1) % 4]
        dy = qy - py
        safe_dy = torch.where(dy == 0, torch.ones_like(dy), dy)
        for line in (y_lo, y_hi):
            t = (line - py) / safe_dy
            cross = (dy != 0) & (t >= 0) & (t <= 1)
            best = torch.maximum(best, torch.where(cross, px + t * (qx - px), ninf))
    return best
