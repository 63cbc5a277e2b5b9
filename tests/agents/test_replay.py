"""ExpertReplay against a one-row-at-a-time reference of per-expert circular buffers."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from highway_srl.agents.gating import expert_action_mask
from highway_srl.agents.replay import ExpertReplay

OBS = 3


class ReferenceBuffers:
    """Algorithm 1's D_i,j written the obvious way: append one transition at a time."""

    def __init__(self, members: int, capacity: int) -> None:
        self.capacity = capacity
        self.slots = [[None] * capacity for _ in range(members)]
        self.ptr = [0] * members
        self.size = [0] * members

    def add(self, member: int, transition: tuple) -> None:
        if member < 0:
            return
        self.slots[member][self.ptr[member]] = transition
        self.ptr[member] = (self.ptr[member] + 1) % self.capacity
        self.size[member] = min(self.size[member] + 1, self.capacity)


def _transitions(n: int, start: int):
    """n distinct transitions; the reward is the global row number, so rows are identifiable."""
    ids = torch.arange(start, start + n, dtype=torch.float32)
    obs = ids[:, None] + torch.arange(OBS) / 10
    return obs, (ids.long() % 4), ids, obs + 100, (ids.long() % 3 == 0)


def _assert_matches(buf: ExpertReplay, ref: ReferenceBuffers) -> None:
    assert buf.size.tolist() == ref.size
    assert buf.ptr.tolist() == ref.ptr
    for m in range(buf.num_members):
        for slot in range(ref.size[m]):
            row = m * buf.capacity + slot
            reward = ref.slots[m][slot]
            assert buf.storage["reward"][row].item() == reward
            obs, action, _, next_obs, done = _transitions(1, int(reward))
            assert torch.equal(buf.storage["obs"][row], obs[0])
            assert torch.equal(buf.storage["next_obs"][row], next_obs[0])
            assert buf.storage["action"][row].item() == action.item()
            assert buf.storage["done"][row].item() == done.item()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.integers(-1, 2), min_size=1, max_size=12), min_size=1, max_size=8))
def test_add_matches_sequential_circular_buffers(calls):
    buf, ref = ExpertReplay(3, OBS, capacity=4), ReferenceBuffers(3, 4)
    start = 0
    for members in calls:
        obs, action, reward, next_obs, done = _transitions(len(members), start)
        buf.add(torch.tensor(members), obs, action, reward, next_obs, done)
        for m, r in zip(members, reward.tolist()):
            ref.add(m, r)
        start += len(members)
    _assert_matches(buf, ref)


def test_many_rows_to_one_member_wrap_around_in_a_single_call():
    buf, ref = ExpertReplay(2, OBS, capacity=5), ReferenceBuffers(2, 5)
    members = [1] * 13 + [0, -1, 0]
    buf.add(torch.tensor(members), *_transitions(len(members), 0))
    for m, r in zip(members, range(len(members))):
        ref.add(m, float(r))
    _assert_matches(buf, ref)
    assert buf.size.tolist() == [2, 5]
    assert sorted(buf.storage["reward"][5:10].tolist()) == [8.0, 9.0, 10.0, 11.0, 12.0]


def test_add_shared_stores_each_transition_in_every_expert_whose_set_contains_its_action():
    buf = ExpertReplay(11, OBS, capacity=8)
    obs, action, reward, next_obs, done = _transitions(4, 0)  # actions 0, 1, 2, 3
    mask = expert_action_mask()[:, action].T  # (B, 11)
    buf.add_shared(mask, obs, action, reward, next_obs, done)
    assert buf.size.tolist() == mask.sum(0).tolist()
    for m in range(11):
        stored = buf.storage["action"][m * 8 : m * 8 + buf.size[m]].tolist()
        assert stored == [a for a in range(4) if mask[a, m]]


def test_sample_draws_only_filled_rows_of_the_requested_members():
    buf = ExpertReplay(3, OBS, capacity=50)
    members = torch.tensor([0] * 3 + [2] * 40)
    buf.add(members, *_transitions(len(members), 0))
    gen = torch.Generator().manual_seed(0)
    batch = buf.sample(torch.tensor([2, 0]), 4000, gen)
    assert batch["obs"].shape == (2, 4000, OBS) and batch["action"].shape == (2, 4000)
    assert batch["done"].dtype == torch.bool and batch["action"].dtype == torch.long
    assert set(batch["reward"][1].tolist()) == {0.0, 1.0, 2.0}
    assert set(batch["reward"][0].tolist()) == {float(r) for r in range(3, 43)}  # all 40, uniformly
    counts = torch.bincount(batch["reward"][0].long())[3:]
    assert counts.min() > 50
    assert torch.equal(batch["next_obs"], batch["obs"] + 100)
    again = buf.sample(torch.tensor([2, 0]), 4000, torch.Generator().manual_seed(0))
    assert torch.equal(again["reward"], batch["reward"])


def test_cost_field_and_state_dict_round_trip():
    buf = ExpertReplay(2, OBS, capacity=6, with_cost=True)
    obs, action, reward, next_obs, done = _transitions(9, 0)
    members = torch.tensor([0, 1, 1, 0, 1, 1, 1, 1, 1])
    with pytest.raises(ValueError, match="cost"):
        buf.add(members, obs, action, reward, next_obs, done)
    buf.add(members, obs, action, reward, next_obs, done, cost=reward * 2)
    copy = ExpertReplay(2, OBS, capacity=6, with_cost=True)
    copy.load_state_dict(buf.state_dict())
    for key in buf.storage:
        assert torch.equal(copy.storage[key], buf.storage[key])
    assert torch.equal(copy.size, buf.size) and torch.equal(copy.ptr, buf.ptr)
    sample = copy.sample(torch.tensor([1]), 16, torch.Generator().manual_seed(0))
    assert torch.equal(sample["cost"], sample["reward"] * 2)
    with pytest.raises(ValueError, match="shape"):
        ExpertReplay(2, OBS, capacity=7, with_cost=True).load_state_dict(buf.state_dict())
