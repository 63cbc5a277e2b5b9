"""The sparsely-gated MoE of §3.4 against a scalar reading of its numbered rule and Table 1."""

from __future__ import annotations

import itertools
from collections import Counter

import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from table_1 import rows

from highway_srl.agents.gating import (
    ACTIONS,
    EXPERT_ACTION_SETS,
    EXPERT_NAMES,
    expert_action_mask,
    explore_gate,
    polite_gate,
    random_expert_actions,
)

F, I, S, L = (ACTIONS.index(a) for a in ("Faster", "Idle", "Slower", "LaneChange"))

# Table 1 (tests/rules/table_1.py): (R*_SV1, R*_SV3, R*_SV2, R*_SV4) -> (a_F, a_S, a_I, a_L), the paper's
# column orders: the table lists Slower before Idle, ACTIONS has Idle before Slower.
TABLE_1 = [((r1, r3, r2, r4), (e["Faster"], e["Slower"], e["Idle"], e["LaneChange"])) for _, (r1, r2, r3, r4), e in rows()]


def _safe_row(row: int) -> list[bool]:
    """Row `row` (0-based) of Table 1 as a mask in ACTIONS order."""
    a_f, a_s, a_i, a_l = TABLE_1[row][1]
    mask = [False] * 4
    mask[F], mask[S], mask[I], mask[L] = bool(a_f), bool(a_s), bool(a_i), bool(a_l)
    return mask


SAFE_ROWS = torch.tensor([_safe_row(r) for r in range(16)])


def _expert_excluding(*actions: int) -> int:
    want = set(range(4)) - set(actions)
    return next(e for e, s in enumerate(EXPERT_ACTION_SETS) if set(s) == want)


def reference_gate(greedy: list[int], safe: list[bool]) -> tuple[int, int, tuple[int, ...]]:
    """The numbered rule of §3.4, one row at a time: (action, expert, consulted actions)."""
    a1 = greedy[0]
    if safe[a1]:
        return a1, 0, (a1,)
    e2 = _expert_excluding(a1)
    a2 = greedy[e2]
    if safe[a2]:
        return a2, e2, (a1, a2)
    e3 = _expert_excluding(a1, a2)
    a3 = greedy[e3]
    if safe[a3]:
        return a3, e3, (a1, a2, a3)
    (a4,) = set(range(4)) - {a1, a2, a3}
    return a4, -1, (a1, a2, a3)


def test_expert_action_sets_are_eqs_37_to_47():
    assert EXPERT_NAMES == ("E1,1", "E2,1", "E2,2", "E2,3", "E2,4", "E3,1", "E3,2", "E3,3", "E3,4", "E3,5", "E3,6")
    assert EXPERT_ACTION_SETS == (
        (0, 1, 2, 3),
        (1, 2, 3),
        (0, 2, 3),
        (0, 1, 3),
        (0, 1, 2),
        (0, 2),
        (0, 1),
        (0, 3),
        (2, 3),
        (1, 2),
        (1, 3),
    )
    mask = expert_action_mask()
    assert mask.shape == (11, 4) and mask.dtype == torch.bool
    assert mask.sum(1).tolist() == [4, 3, 3, 3, 3, 2, 2, 2, 2, 2, 2]


def test_table_1_has_a_safe_action_in_every_row_and_matches_the_reading_notes():
    r1, r3, r2, r4 = (torch.tensor([row[0][k] for row in TABLE_1], dtype=torch.bool) for k in range(4))
    assert SAFE_ROWS.any(1).all()
    assert torch.equal(SAFE_ROWS[:, F], r1)
    assert torch.equal(SAFE_ROWS[:, S], r3)
    assert torch.equal(SAFE_ROWS[:, L], r2 & r4)
    assert torch.equal(SAFE_ROWS[:, I], r1 | (~r3 & ~(r2 & r4)))


proposals = st.tuples(*(st.sampled_from(s) for s in EXPERT_ACTION_SETS)).map(list)
gate_rows = st.lists(st.tuples(proposals, st.integers(0, 15)), min_size=1, max_size=40)


@settings(max_examples=300, deadline=None)
@given(gate_rows)
def test_polite_gate_follows_the_numbered_rule_and_always_acts_safely(rows):
    greedy = torch.tensor([g for g, _ in rows])
    safe = SAFE_ROWS[torch.tensor([r for _, r in rows])]
    action, expert = polite_gate(greedy, safe)
    assert action.dtype == torch.long and expert.dtype == torch.long and action.shape == (len(rows),)
    for b, (g, r) in enumerate(rows):
        row_safe = _safe_row(r)
        a, e = action[b].item(), expert[b].item()
        want_a, want_e, consulted = reference_gate(g, row_safe)
        assert (a, e) == (want_a, want_e)
        assert row_safe[a], "executed action must be safe"
        assert (e == 0) == row_safe[g[0]], "E1,1 acts iff its action is safe"
        if e >= 0:
            assert a in EXPERT_ACTION_SETS[e] and a == g[e]
        else:
            assert len(consulted) == 3 and not any(row_safe[c] for c in consulted)
            assert a not in consulted


def test_every_proposal_combination_and_table_row_gives_a_safe_action():
    # All 4 * 3^4 * 2^6 proposal vectors would be 20,736 per row; the gate only reads the
    # consulted ones, so the 24 orderings of A* (a1, a2, a3, rest) cover every path.
    rows = []
    for order in itertools.permutations(range(4)):
        g = [EXPERT_ACTION_SETS[e][0] for e in range(11)]
        g[0] = order[0]
        g[_expert_excluding(order[0])] = order[1]
        g[_expert_excluding(order[0], order[1])] = order[2]
        rows.append(g)
    greedy = torch.tensor(rows).repeat(16, 1)
    safe = SAFE_ROWS.repeat_interleave(len(rows), 0)
    action, expert = polite_gate(greedy, safe)
    assert safe.gather(1, action[:, None]).all()
    for b in range(greedy.shape[0]):
        assert (action[b].item(), expert[b].item()) == reference_gate(greedy[b].tolist(), safe[b].tolist())[:2]


def test_figure_2_example_under_the_numbered_rule():
    # Fig. 2: E1,1 rejected, E2,2 rejected, E3,1 executes LaneChange. E2,2 is consulted only when
    # a1 = Idle. Its rejected action a2 then decides the layer-3 expert: A*\{Idle, a2}. E3,1 is
    # A*\{Idle, LaneChange} = {Faster, Slower}, reached only if a2 = LaneChange was rejected, and
    # it cannot propose LaneChange. So the figure is inconsistent with Eqs. 42-47 and the numbered
    # rule; we test the rule. The nearest consistent case: row 13 of Table 1 (only LaneChange
    # safe), a1 = Idle, a2 = Slower -> E3,3 = {Faster, LaneChange} proposes LaneChange.
    safe = SAFE_ROWS[12:13]
    assert safe[0].tolist() == [False, False, False, True]
    g = [EXPERT_ACTION_SETS[e][0] for e in range(11)]
    g[EXPERT_NAMES.index("E1,1")] = I
    g[EXPERT_NAMES.index("E2,2")] = S
    g[EXPERT_NAMES.index("E3,3")] = L
    action, expert = polite_gate(torch.tensor([g]), safe)
    assert (ACTIONS[action.item()], EXPERT_NAMES[expert.item()]) == ("LaneChange", "E3,3")
    # with a2 = Faster the layer-3 expert is E3,4 = {Slower, LaneChange}
    g[EXPERT_NAMES.index("E2,2")] = F
    g[EXPERT_NAMES.index("E3,4")] = L
    action, expert = polite_gate(torch.tensor([g]), safe)
    assert (ACTIONS[action.item()], EXPERT_NAMES[expert.item()]) == ("LaneChange", "E3,4")
    # the figure's own path (a2 = LaneChange rejected, E3,1 consulted) needs LaneChange unsafe
    g[EXPERT_NAMES.index("E2,2")] = L
    g[EXPERT_NAMES.index("E3,1")] = S
    only_faster = torch.tensor([[True, False, False, False]])
    action, expert = polite_gate(torch.tensor([g]), only_faster)
    assert (ACTIONS[action.item()], expert.item()) == ("Faster", -1)  # step 4: the remaining action


def test_random_expert_actions_are_uniform_inside_each_set():
    gen = torch.Generator().manual_seed(0)
    acts = random_expert_actions(torch.rand(20_000, 11, generator=gen))
    assert acts.shape == (20_000, 11)
    for e, s in enumerate(EXPERT_ACTION_SETS):
        counts = torch.bincount(acts[:, e], minlength=4).float() / acts.shape[0]
        for a in range(4):
            want = 1 / len(s) if a in s else 0.0
            assert abs(counts[a].item() - want) < 0.02


def _algorithm_2_distribution(safe: list[bool]) -> dict[tuple[int, int], float]:
    """Exact (action, expert) law of ExG read sequentially: each consulted expert draws uniformly."""
    law: Counter = Counter()
    for a1 in range(4):
        if safe[a1]:
            law[(a1, 0)] += 1 / 4
            continue
        e2 = _expert_excluding(a1)
        for a2 in EXPERT_ACTION_SETS[e2]:
            p2 = 1 / 4 / 3
            if safe[a2]:
                law[(a2, e2)] += p2
                continue
            e3 = _expert_excluding(a1, a2)
            for a3 in EXPERT_ACTION_SETS[e3]:
                if safe[a3]:
                    law[(a3, e3)] += p2 / 2
                else:
                    (a4,) = set(range(4)) - {a1, a2, a3}
                    law[(a4, -1)] += p2 / 2
    return dict(law)


def test_explore_gate_has_the_law_of_algorithm_2():
    gen = torch.Generator().manual_seed(1)
    n = 20_000
    for row in (0, 4, 8, 12, 15):
        safe = SAFE_ROWS[row].expand(n, -1)
        action, expert = explore_gate(safe, gen)
        assert safe.gather(1, action[:, None]).all()
        seen = Counter(zip(action.tolist(), expert.tolist()))
        law = _algorithm_2_distribution(_safe_row(row))
        assert set(seen) <= set(law)
        for key, p in law.items():
            assert abs(seen[key] / n - p) < 0.015, (row, key)
