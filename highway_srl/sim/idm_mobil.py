"""Surrounding traffic: lane occupancy, leaders and followers per lane, IDM car following, MOBIL parameters.

Neighbour search keeps each env's vehicles sorted by x (the order is cached in the state and only the
envs where an overtake, a recycle or a reset broke it are re-sorted) and, per lane, finds the next
occupant ahead and behind in sorted order with running min/max scans: O(N log N) per env and no
(B, N, N) tensors, which is what makes dense levels (N = 45) cheap.

Speed notes (CPU): torch.where with an irregular mask runs a branchy scalar loop (about 10 ns an element,
30x an add), so the hot path blends with arithmetic and uses large finite sentinels instead of masks.
"""

from __future__ import annotations

import torch

from highway_srl.constants import VEHICLE_LENGTH_M, VEHICLE_WIDTH_M
from highway_srl.sim.selection import TAKE_MAX, take_flat  # noqa: F401  (re-exported)

# IDM parameters shared by every style (the style sets the jam distance s0 = DH and the desired speed).
IDM_ACCEL_MPS2 = 1.5  # a: maximum acceleration
IDM_COMFORT_BRAKE_MPS2 = 2.0  # b: comfortable deceleration
IDM_TIME_HEADWAY_S = 1.0  # T
IDM_DELTA = 4.0
SV_BRAKE_LIMIT_MPS2 = 6.0  # physical limit IDM's output is clamped to
_SQRT_AB2 = 2.0 * (IDM_ACCEL_MPS2 * IDM_COMFORT_BRAKE_MPS2) ** 0.5
# MOBIL parameters
MOBIL_POLITENESS = 0.3
MOBIL_THRESHOLD_MPS2 = 0.2
MOBIL_SAFE_BRAKE_MPS2 = 3.0  # neither the changer nor its new follower may need to brake harder than this
MOBIL_EGO_SAFE_BRAKE_MPS2 = 1.5  # stricter when the new follower is the ego: nominal SVs do not cut it off
MOBIL_MIN_GAP_M = 2.0  # bumper-to-bumper room required ahead and behind in the target lane
MANDATORY_BONUS_MPS2 = 10.0  # merging / exiting vehicles change whenever it is safe
# A lane change under way (not yet across the boundary) is abandoned when it turns unsafe (hysteresis
# over the MOBIL thresholds so that a change is not started and abandoned in the same second).
ABORT_BRAKE_MPS2 = 4.5
ABORT_EGO_BRAKE_MPS2 = 3.0
ABORT_GAP_M = 1.0
LANE_CHANGE_TIME_S = 3.0  # a change is only started if it can be completed inside the change window
# A vehicle occupies every lane its footprint reaches, widened by this margin (more than one step of
# lateral travel), besides its own and its target lane: followers there see it, and contacts are checked.
OCCUPANCY_MARGIN_M = 0.3
FAR_M = 1.0e6  # sentinel position of a missing leader (+) or follower (-)


def approx_half_width(heading: torch.Tensor) -> torch.Tensor:
    """An upper bound (within 0.1 m for |heading| <= 0.6) of a rotated box's half extent along y, without
    trigonometry: B/2 (1 - h^2/2) + L/2 |h| >= B/2 cos h + L/2 sin |h|."""
    h = heading.abs()
    return 0.5 * VEHICLE_WIDTH_M * (1.0 - 0.5 * h * h) + 0.5 * VEHICLE_LENGTH_M * h


def occupancy(y, half_width, lane, target_lane, num_lanes: int, lane_width_m: float) -> torch.Tensor:
    """(K, B, N) bool: vehicle n occupies lane k (its own lane, its target lane, or lane k's band is
    within its footprint's lateral extent half_width (B, N) plus OCCUPANCY_MARGIN_M)."""
    lo = y - half_width - OCCUPANCY_MARGIN_M
    hi = y + half_width + OCCUPANCY_MARGIN_M
    rows = []
    for k in range(num_lanes):
        band = (hi > (k - 0.5) * lane_width_m) & (lo < (k + 0.5) * lane_width_m)
        rows.append(band | (lane == k) | (target_lane == k))
    return torch.stack(rows)


def sorted_order(x: torch.Tensor, order: torch.Tensor | None = None, static: bool = False) -> torch.Tensor:
    """(B, N) long: the stable ascending order of x along dim 1 (ties by index), reusing `order` in the
    envs where it still holds, so that only envs where vehicles passed each other are sorted again.
    static: every env is sorted (the same order: a stable order is unique), without a host read."""
    if order is None or static:
        return torch.sort(x, dim=1, stable=True).indices
    xs = x.gather(1, order)
    # a row whose cached order has a pair out of order, or level (x equal: rare; the stable sort then gives
    # the order that row already has, ties by index): sorted again. Counted with sum, not any: any's
    # reduction along a short row is 3x slower on the CPU.
    rows = ((xs[:, 1:] - xs[:, :-1]) <= 0).sum(1).nonzero().squeeze(1)
    if rows.numel() == 0:
        return order
    order = order.clone()
    order[rows] = torch.sort(x[rows], dim=1, stable=True).indices
    return order


_KEY = 128


def _exclusive_scan(occupancy: torch.Tensor, order: torch.Tensor, key: torch.Tensor, none: int, running):
    """(K, B, N + 1) int32: column p holds running (torch.cummin / cummax) over the keys (B, N) int32 of the
    occupants at positions before p of `order` (B, N), `none` where there is none (occupancy (K, B, N)
    bool). The keys are written one column to the right of a padding column whose key is `none`, which makes
    the scan exclusive without a shifted copy."""
    k, b, n = occupancy.shape
    pad_front = lambda t: torch.nn.functional.pad(t, (1, 0))  # noqa: E731 (a zero column before column 0)
    # column 0 reads vehicle 0's occupancy, multiplied by the padding's key - none = 0 below
    occ = torch.gather(occupancy, 2, pad_front(order).expand(k, b, n + 1))
    # torch.cummin / cummax, not log2(N) shifted min steps: compiled, each shifted step was inlined into
    # the next (2^5 recomputations at N = 25, 60 % of the compiled static step at 4,096 envs;
    # docs/benchmarks.md)
    return running(none + occ.to(torch.int32) * pad_front(key - none), -1).values  # key where occupied, else none


def neighbour_keys(occupancy: torch.Tensor, order: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Every vehicle's nearest occupant ahead in each lane, and the scan followers_of reads followers from.

    occupancy (K, B, N) bool; order (B, N) the ascending stable order of x (sorted_order). Returns leader
    (K, B, N) long, N = none; behind_keys (K, B, N + 1) int32, column p: the key of the nearest occupant
    before ascending position p. The scans run on int32 keys position * 128 + vehicle index (N < 128),
    so the nearest occupant's index comes out of a running min / max without a lookup (int32: half the
    bytes of int64 in every pass over the keys). The leaders' scan runs over the vehicles in descending order,
    so that "ahead" is "before" and no (K, B, N) tensor is flipped: only the (B, N) order and keys."""
    K, B, N = occupancy.shape
    if N >= _KEY:
        raise ValueError(f"at most {_KEY - 1} vehicles per env are supported, got {N}")
    key = torch.arange(0, N * _KEY, _KEY, dtype=torch.int32, device=order.device) + order.to(torch.int32)
    desc = order.flip(-1)
    # none = N modulo _KEY: above every key for the min, below every key for the max
    ahead = _exclusive_scan(occupancy, desc, key.flip(-1), _KEY * _KEY + N, torch.cummin)
    leader = torch.empty((K, B, N), dtype=torch.int32, device=order.device)
    leader.scatter_(2, desc.expand(K, B, N), ahead[..., :N] & (_KEY - 1))
    behind = _exclusive_scan(occupancy, order, key, N - _KEY, torch.cummax)
    return leader.long(), behind


def followers_of(behind_keys: torch.Tensor, rank: torch.Tensor, k, b, i) -> torch.Tensor:
    """Nearest occupant behind vehicle i of env b in lane k, N where there is none (b, i (M,) long; k (M,)
    or (L, M), lanes asked at once: the vehicle's rank is read once); behind_keys from neighbour_keys, rank
    from inverse_order."""
    _, n_envs, n1 = behind_keys.shape
    # flat reads, not behind_keys[k, b, rank[b, i]]: advanced indexing with three index tensors takes a slow
    # general path on the CPU
    r = take_flat(rank, b * (n1 - 1) + i)
    return (take_flat(behind_keys, (k * n_envs + b) * n1 + r) & (_KEY - 1)).long()


def inverse_order(order: torch.Tensor) -> torch.Tensor:
    """(B, N) rank of each vehicle in the sorted order."""
    b, n = order.shape
    return torch.empty_like(order).scatter_(1, order, torch.arange(n, device=order.device).expand(b, n))


def lane_neighbours(
    x: torch.Tensor, occupancy: torch.Tensor, order: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Nearest vehicle ahead and behind in each lane, for every vehicle.

    x: (B, N) positions; occupancy: (K, B, N) bool, vehicle n occupies lane k; order: (B, N) the stable
    ascending order of x (see sorted_order), computed here if not given.
    Returns leader, follower: (K, B, N) long vehicle indices, N where there is none (so that they can
    index arrays padded with one sentinel column). A vehicle is never its own neighbour; ahead / behind
    follow the stable order, so vehicles level in x are ordered by index.

    The scans run on keys position * 128 + vehicle index (N < 128), so the nearest occupant's index comes
    out of the running min / max without a lookup. (The step itself only needs every leader, and the
    followers of a few vehicles: see neighbour_keys and followers_of.)
    """
    K, B, N = occupancy.shape
    if order is None:
        order = sorted_order(x)
    leader, behind = neighbour_keys(occupancy, order)
    follower = torch.empty((K, B, N), dtype=torch.int32, device=x.device)
    follower.scatter_(2, order.expand(K, B, N), behind[..., :N] & (_KEY - 1))
    return leader, follower.long()


def pad(values: torch.Tensor, fill: float) -> torch.Tensor:
    """(B, N) -> (B, N + 1) with a sentinel column, indexable by neighbour indices (N = none)."""
    return torch.cat([values, torch.full_like(values[:, :1], fill)], 1)


def idm_accel(v, v0, s0, gap, v_lead, has_lead):
    """Intelligent Driver Model acceleration (m/s^2), clamped to the physical braking limit.

    v, v0, s0: follower speed, desired speed, jam distance; gap: bumper-to-bumper distance to the leader;
    v_lead: leader speed; has_lead: False means free road.
    """
    # powers as products: pow() takes a different (vectorised or scalar) code path depending on the
    # tensor's length and can differ in the last bit, which would make an env depend on its batch
    free = idm_free_term(v, v0)
    s_star = s0 + (v * IDM_TIME_HEADWAY_S + v * (v - v_lead) / _SQRT_AB2).clamp(min=0.0)
    r = s_star / gap.clamp(min=0.05)
    inter = torch.where(has_lead, r * r, torch.zeros_like(v))
    return (IDM_ACCEL_MPS2 * (free - inter)).clamp(min=-SV_BRAKE_LIMIT_MPS2)


def idm_free_term(v: torch.Tensor, v0: torch.Tensor) -> torch.Tensor:
    """1 - (v / v0)^4, the free-road part of IDM (computed once per step, shared by every lane)."""
    r = v / v0.clamp(min=0.1)
    r = r * r
    return 1.0 - r * r


def idm_accel_fast(free, v, s0, gap, v_lead):
    """idm_accel with the free term given and a missing leader encoded as a huge gap (FAR_M): no masks."""
    s_star = s0 + (v * IDM_TIME_HEADWAY_S + v * (v - v_lead) / _SQRT_AB2).clamp(min=0.0)
    r = s_star / gap.clamp(min=0.05)
    return (IDM_ACCEL_MPS2 * (free - r * r)).clamp(min=-SV_BRAKE_LIMIT_MPS2)


def gather_lead(values: torch.Tensor, idx: torch.Tensor, fill: float) -> torch.Tensor:
    """values (B, N) read at vehicle indices idx (B, M); indices outside [0, N) (-1 or N: none) -> fill."""
    n = values.shape[1]
    ok = (idx >= 0) & (idx < n)
    out = torch.gather(values, 1, idx.clamp(0, n - 1))
    return torch.where(ok, out, torch.full_like(out, fill))
