"""The counter-based random numbers (sim/rng.py) against a plain-Python SplitMix64 finaliser."""

from __future__ import annotations

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from highway_srl.sim import rng

MASK = (1 << 64) - 1


def mix64_reference(z: int) -> int:
    """SplitMix64's finaliser on unsigned 64-bit integers (Steele, Lea and Flood 2014)."""
    z = (z + 0x9E3779B97F4A7C15) & MASK
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return z ^ (z >> 31)


def signed(z: int) -> int:
    return z - (1 << 64) if z >= 1 << 63 else z


def key_reference(seed: int, episode: int, step: int, stream: int) -> int:
    k = mix64_reference((seed * 1_000_003 + episode) & MASK)
    k = mix64_reference((k + stream * 7919) & MASK)
    return signed(mix64_reference((k + step) & MASK))


def test_golden_values():
    # SplitMix64 seeded with 0 gives 0xE220A8397B1DCDAF as its first output: mix64(0) in this form
    assert rng.mix64(torch.tensor([0])).item() == signed(0xE220A8397B1DCDAF)
    assert rng.key(torch.tensor([0]), torch.tensor([0]), 0, 0).item() == key_reference(0, 0, 0, 0)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**31), episode=st.integers(0, 10**6), step=st.integers(0, 10**4), stream=st.integers(0, 64))
def test_key_and_its_episode_part_agree_with_the_reference(seed, episode, step, stream):
    s, e = torch.tensor([seed]), torch.tensor([episode])
    want = key_reference(seed, episode, step, stream)
    assert rng.key(s, e, step, stream).item() == want
    assert rng.step_key(rng.episode_key(s, e), step, stream).item() == want


@settings(max_examples=30, deadline=None)
@given(seeds=st.lists(st.integers(0, 2**31), min_size=1, max_size=4), step=st.integers(0, 10**4),
       widths=st.lists(st.one_of(st.none(), st.integers(1, 12)), min_size=1, max_size=9))
def test_all_streams_at_once_equal_one_stream_at_a_time(seeds, step, widths):
    episode_k = rng.episode_key(torch.tensor(seeds), torch.arange(len(seeds)))
    draws = rng.uniforms(episode_k, step, tuple(widths))
    for stream, width in enumerate(widths):
        assert torch.equal(draws[stream], rng.uniform(rng.step_key(episode_k, step, stream), width))
