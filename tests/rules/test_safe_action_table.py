"""Table 1 (§3.4): the safe-action mask, checked against the paper's 16 rows typed in."""

import itertools

import torch

from highway_srl.rules import ACTIONS, safe_action_mask
from highway_srl.rules.safe_actions import safe_action_mask_from

from table_1 import rows  # tests/rules/table_1.py, the golden Table 1


def test_actions_order_is_faster_idle_slower_lanechange():
    assert ACTIONS == ("Faster", "Idle", "Slower", "LaneChange")


def test_each_of_the_16_rows_of_table_1():
    for no, (r1, r2, r3, r4), expected in rows():
        mask = safe_action_mask(torch.tensor(bool(r1)), torch.tensor(bool(r2)), torch.tensor(bool(r3)),
                                torch.tensor(bool(r4)))
        got = {a: int(mask[i]) for i, a in enumerate(ACTIONS)}
        assert got == expected, f"row {no}"


def test_table_1_rows_cover_all_16_combinations_and_each_has_a_safe_action():
    seen = {r for _, r, _ in rows()}
    assert seen == set(itertools.product((0, 1), repeat=4))
    assert all(any(e.values()) for _, _, e in rows())


def test_batched_mask_equals_row_by_row():
    combos = torch.tensor(list(itertools.product((False, True), repeat=4)))  # (16, 4) as R1..R4
    batch = safe_action_mask_from(combos)
    assert batch.shape == (16, 4)
    for k in range(16):
        one = safe_action_mask(*(combos[k, i] for i in range(4)))
        assert torch.equal(batch[k], one)
