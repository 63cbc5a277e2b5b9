"""The sparsely-gated mixture of experts of §3.4: 11 experts over subsets of A*, Eqs. 37-47.

Layer 1 has one expert over all four actions, layer 2 four experts that each drop one
action, layer 3 six experts that each drop a pair. The gate consults at most one expert
per layer, so the whole cascade is a few table look-ups and `torch.where`s over the batch.

Expert indices 0..10 follow the paper's order E1,1; E2,1..E2,4; E3,1..E3,6.
"""

from __future__ import annotations

import torch

from highway_srl.rules.safe_actions import ACTIONS, FASTER, IDLE, LANE_CHANGE, NUM_ACTIONS, SLOWER  # noqa: F401


def _without(*dropped: int) -> tuple[int, ...]:
    return tuple(a for a in range(NUM_ACTIONS) if a not in dropped)


EXPERT_ACTION_SETS: tuple[tuple[int, ...], ...] = (
    _without(),  # Eq. 37  A_1,1 = A*
    _without(FASTER),  # Eq. 38  A_2,1
    _without(IDLE),  # Eq. 39  A_2,2
    _without(SLOWER),  # Eq. 40  A_2,3
    _without(LANE_CHANGE),  # Eq. 41  A_2,4
    _without(IDLE, LANE_CHANGE),  # Eq. 42  A_3,1
    _without(SLOWER, LANE_CHANGE),  # Eq. 43  A_3,2
    _without(SLOWER, IDLE),  # Eq. 44  A_3,3
    _without(FASTER, IDLE),  # Eq. 45  A_3,4
    _without(FASTER, LANE_CHANGE),  # Eq. 46  A_3,5
    _without(FASTER, SLOWER),  # Eq. 47  A_3,6
)
EXPERT_NAMES = ("E1,1", "E2,1", "E2,2", "E2,3", "E2,4", "E3,1", "E3,2", "E3,3", "E3,4", "E3,5", "E3,6")
NUM_EXPERTS = len(EXPERT_ACTION_SETS)
FALLBACK = -1  # "expert" of the step-4 fallback action: no network owns it (the paper's j = 0)


def expert_action_mask(device: torch.device | str | None = None) -> torch.Tensor:
    """(11, 4) bool: row e is true on the actions of A_e."""
    mask = torch.zeros(NUM_EXPERTS, NUM_ACTIONS, dtype=torch.bool)
    for e, actions in enumerate(EXPERT_ACTION_SETS):
        mask[e, list(actions)] = True
    return mask.to(device)


def _lookup_tables() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Layer-2 expert by rejected action (4,), layer-3 expert by rejected pair (4, 4; -1 on
    the diagonal, which the cascade never reaches), and for random proposals each set padded
    to 4 entries (11, 4) with its size (11,)."""
    sets = [frozenset(s) for s in EXPERT_ACTION_SETS]
    layer2 = torch.tensor([sets.index(frozenset(_without(a))) for a in range(NUM_ACTIONS)])
    layer3 = torch.full((NUM_ACTIONS, NUM_ACTIONS), -1, dtype=torch.long)
    for a in range(NUM_ACTIONS):
        for b in range(NUM_ACTIONS):
            if a != b:
                layer3[a, b] = sets.index(frozenset(_without(a, b)))
    padded = torch.tensor([list(s) + [s[0]] * (NUM_ACTIONS - len(s)) for s in EXPERT_ACTION_SETS])
    sizes = torch.tensor([len(s) for s in EXPERT_ACTION_SETS])
    return layer2, layer3, padded, sizes


_LAYER2_BY_REJECTED, _LAYER3_BY_REJECTED_PAIR, _PADDED_SETS, _SET_SIZES = _lookup_tables()
_TABLE_CACHE: dict[torch.device, tuple[torch.Tensor, ...]] = {}


def gate_tables(device: torch.device) -> tuple[torch.Tensor, ...]:
    """The gate's look-up tables on device, copied there once for the whole run, not once per call. A
    traced step should find them made (MoERMSRL.start): one it makes itself is recompiled on its next call
    (the cache's content is guarded on)."""
    if device not in _TABLE_CACHE:
        _TABLE_CACHE[device] = tuple(
            t.to(device) for t in (_LAYER2_BY_REJECTED, _LAYER3_BY_REJECTED_PAIR, _PADDED_SETS, _SET_SIZES)
        )
    return _TABLE_CACHE[device]


def polite_gate(greedy: torch.Tensor, safe: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Polite gating PoG (Algorithm 3), written as the numbered rule of §3.4.

    greedy: (B, 11) long, each expert's proposed action (an index into ACTIONS inside its set).
    safe: (B, 4) bool, the safe-action mask of Table 1 (every row has a safe action).
    Returns action (B,) long and expert (B,) long: the index of the acting expert, or -1 when
    step 4 executes the one remaining action (no expert proposed it, so none owns the transition).

    1. E1,1's action a1 if safe;
    2. else the layer-2 expert whose set is A* minus {a1}, if its action a2 is safe;
    3. else the layer-3 expert whose set is A* minus {a1, a2}, if its action a3 is safe;
    4. else A* minus {a1, a2, a3}: a1, a2, a3 are distinct and unsafe, and some action is safe,
       so the last one is. This also covers Algorithm 3's "A_3,j minus act_3,j" branch, which is
       the same action; its final "Idle" branch is unreachable.
    """
    layer2, layer3, _, _ = gate_tables(greedy.device)
    a1 = greedy[:, 0]
    e2 = layer2[a1]
    a2 = greedy.gather(1, e2.unsqueeze(1)).squeeze(1)
    e3 = layer3[a1, a2]
    # clamp: e3 is -1 only if a2 == a1, which a greedy action inside A_2,j can never be
    a3 = greedy.gather(1, e3.clamp(min=0).unsqueeze(1)).squeeze(1)
    a4 = (NUM_ACTIONS * (NUM_ACTIONS - 1) // 2) - a1 - a2 - a3  # 0+1+2+3 minus the three others
    ok1, ok2, ok3 = (safe.gather(1, a.unsqueeze(1)).squeeze(1) for a in (a1, a2, a3))
    action = torch.where(ok1, a1, torch.where(ok2, a2, torch.where(ok3, a3, a4)))
    expert = torch.where(
        ok1, torch.zeros_like(a1), torch.where(ok2, e2, torch.where(ok3, e3, torch.full_like(a1, FALLBACK)))
    )
    return action, expert


def random_expert_actions(u: torch.Tensor) -> torch.Tensor:
    """(B, 11) long: for every row and expert, an action drawn uniformly from the expert's set, at the
    uniforms u (B, 11) in [0, 1) (drawn by the caller: a traced step takes them as an input)."""
    _, _, padded, sizes = gate_tables(u.device)
    slot = (u * sizes).long().clamp_(max=NUM_ACTIONS - 1)  # clamp guards u*size rounding up to size
    return padded.unsqueeze(0).expand(u.shape[0], -1, -1).gather(2, slot.unsqueeze(2)).squeeze(2)


def explore_gate(safe: torch.Tensor, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Exploration gating ExG (Algorithm 2). safe: (B, 4) bool -> action (B,), expert (B,).

    generator, if given, must live on safe's device.

    Algorithm 2 runs the same cascade as PoG, but each consulted expert proposes a uniformly
    random action from its own set instead of its greedy one. Drawing a proposal for all 11
    experts and running `polite_gate` is the same distribution: the cascade reads only the
    consulted experts' proposals, each an independent uniform draw from its set, and which
    expert is consulted next depends only on earlier proposals.
    """
    u = torch.rand(safe.shape[0], NUM_EXPERTS, generator=generator, device=safe.device)
    return polite_gate(random_expert_actions(u), safe)
