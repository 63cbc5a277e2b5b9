"""Counter-based random numbers: a draw is a pure function of (seed, episode, step, stream, index).

Why not torch.Generator: with one generator per batch, what env b sees depends on how many other envs
share the batch. Hashing counters makes env b with seed s produce the same episode alone or in a batch
of 65,536, on CPU or CUDA, and lets an env be reset without touching the others' streams.
The hash is SplitMix64's finaliser on int64 tensors (wrap-around multiplication, logical shifts by mask).
"""

from __future__ import annotations

import torch

_M1 = -4658895280553007687  # 0xBF58476D1CE4E5B9 as int64
_M2 = -7723592293110705685  # 0x94D049BB133111EB
_GOLDEN = -7046029254386353131  # 0x9E3779B97F4A7C15


def _shr(z: torch.Tensor, k: int) -> torch.Tensor:
    return (z >> k) & ((1 << (64 - k)) - 1)


def mix64(z: torch.Tensor) -> torch.Tensor:
    z = z + _GOLDEN
    z = (z ^ _shr(z, 30)) * _M1
    z = (z ^ _shr(z, 27)) * _M2
    return z ^ _shr(z, 31)


def key(seed: torch.Tensor, episode: torch.Tensor, step: torch.Tensor | int, stream: int) -> torch.Tensor:
    """(B,) int64 key for one stream of one step of one episode of each env."""
    return step_key(episode_key(seed, episode), step, stream)


def episode_key(seed: torch.Tensor, episode: torch.Tensor) -> torch.Tensor:
    """(B,) int64: the part of key() that one episode's streams share (computed once where many are drawn)."""
    return mix64(seed * 1_000_003 + episode)


def step_key(episode_k: torch.Tensor, step: torch.Tensor | int, stream: int) -> torch.Tensor:
    """key(seed, episode, step, stream) from episode_key(seed, episode)."""
    return mix64(mix64(episode_k + stream * 7919) + step)


def uniform(k: torch.Tensor, n: int | None = None) -> torch.Tensor:
    """Uniform [0, 1) float32 draws: (B,) if n is None, else (B, n), one per index 0..n-1."""
    z = k if n is None else k[:, None] * 31 + torch.arange(n, device=k.device, dtype=torch.int64)
    z = mix64(z)
    # top 24 bits -> exactly representable float32 in [0, 1)
    return _shr(z, 40).to(torch.float32) * (1.0 / (1 << 24))


def uniform_at(k: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """The draws uniform(k, n)[:, index] would give, for keys k and indices index of equal shape (M,)."""
    z = mix64(k * 31 + index)
    return _shr(z, 40).to(torch.float32) * (1.0 / (1 << 24))


def uniforms(episode_k: torch.Tensor, step: int, widths: tuple[int | None, ...]) -> list[torch.Tensor]:
    """[uniform(step_key(episode_k, step, s), widths[s]) for each stream s], bit for bit, in three hashes.

    Why: a spawn draws eight streams of a handful of numbers each; one hash per stream and per key made
    its ~330 small operations a tenth of a 4,096-env step. Here all streams go through each hash at once,
    padded to the widest (a width of None is a (B,) draw, whose hash input is the key itself).
    """
    dev = episode_k.device
    s = len(widths)
    k = mix64(mix64(episode_k + torch.arange(0, s * 7919, 7919, device=dev)[:, None]) + step)  # (S, B)
    width = max(w or 1 for w in widths)
    scale = torch.tensor([1 if w is None else 31 for w in widths], device=dev)
    index = torch.arange(width, device=dev) * scale.ne(1)[:, None]  # (S, width); 0 for the (B,) draws
    z = mix64(k[:, :, None] * scale[:, None, None] + index[:, None, :])  # (S, B, width)
    u = _shr(z, 40).to(torch.float32) * (1.0 / (1 << 24))
    return [u[i, :, 0] if w is None else u[i, :, :w] for i, w in enumerate(widths)]


def randint(k: torch.Tensor, high: torch.Tensor | int, n: int | None = None) -> torch.Tensor:
    """Uniform integers in [0, high)."""
    return to_int(uniform(k, n), high)


def to_int(u: torch.Tensor, high: torch.Tensor | int) -> torch.Tensor:
    """Uniform draws u in [0, 1) as integers in [0, high)."""
    # u < 1 - 2**-24, so u * high < high for any high below 2**24
    return (u * high).long()
