"""Oriented-box collision (separating-axis test) and the drivable corridor check."""

from __future__ import annotations

import torch

from highway_srl.constants import VEHICLE_LENGTH_M, VEHICLE_WIDTH_M


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
    overlap = torch.ones_like(dx, dtype=torch.bool)
    for nx, ny in ((ca, sa), (-sa, ca), (cb, sb), (-sb, cb)):
        ra = hl * (ca * nx + sa * ny).abs() + hw * (-sa * nx + ca * ny).abs()
        rb = hl * (cb * nx + sb * ny).abs() + hw * (-sb * nx + cb * ny).abs()
        overlap &= (dx * nx + dy * ny).abs() <= ra + rb
    return overlap


def lateral_half_extent(heading: torch.Tensor, length_m: float = VEHICLE_LENGTH_M, width_m: float = VEHICLE_WIDTH_M):
    """Half of a rotated box's extent along y (m)."""
    return 0.5 * width_m * torch.cos(heading).abs() + 0.5 * length_m * torch.sin(heading).abs()
