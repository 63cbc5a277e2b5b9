"""The study's statistics with the seed as the unit: intervals over seeds, the pooled Wilson interval beside
them, a two-proportion test, a bootstrap over seeds, Pareto dominance beyond an interval, collapsed seeds.

Why the seed: the paper's protocol is 10 independent runs of 100 episodes each. Episodes of one run share
its trained model, so pooling them as independent draws understates the spread between runs; a seed that
collapsed (learned to wait, or to crash) is one unit of ten, not 100 unlucky episodes. Pure functions on
numbers, no files; deterministic (the bootstrap draws from a fixed seed).
"""

from __future__ import annotations

import math
import random
import statistics
from dataclasses import dataclass

from highway_srl.rules.metrics import t_quantile, wilson_interval

CONFIDENCE = 0.95
SIGNIFICANCE = 0.05  # a difference "matters" only with p below this
BOOTSTRAP_DRAWS = 10_000
BOOTSTRAP_SEED = 29
COLLAPSE_GAP = 0.2  # a seed whose rate is this far below the median of its job's seeds has collapsed


@dataclass(frozen=True)
class Interval:
    """A mean over n units with its 95 % interval; low / high None when n < 2 (no spread to estimate)."""

    mean: float
    low: float | None
    high: float | None
    n: int


def t_interval(values, confidence: float = CONFIDENCE) -> Interval | None:
    """Mean of `values` (None skipped) with its Student t interval; None without a value."""
    vals = [float(v) for v in values if v is not None and not math.isnan(float(v))]
    if not vals:
        return None
    mean = sum(vals) / len(vals)
    if len(vals) < 2:
        return Interval(mean, None, None, 1)
    half = t_quantile(confidence, len(vals) - 1) * statistics.stdev(vals) / math.sqrt(len(vals))
    return Interval(mean, mean - half, mean + half, len(vals))


def clip_rate(iv: Interval | None) -> Interval | None:
    """A rate's t interval cut to [0, 1]: a t interval is symmetric, a rate is not (seeds at 1.00, 1.00 and
    0.98 give an upper bound above 1, which no rate reaches)."""
    if iv is None or iv.low is None:
        return iv
    return Interval(iv.mean, max(0.0, iv.low), min(1.0, iv.high), iv.n)


def wilson(successes: int, n: int, confidence: float = CONFIDENCE) -> Interval:
    """The pooled rate successes / n with its Wilson score interval (episodes as the unit)."""
    e = wilson_interval(successes, n, confidence)
    return Interval(e.value, e.low, e.high, n)


def normal_two_sided_p(z: float) -> float:
    """P(|Z| >= |z|) for a standard normal Z."""
    return math.erfc(abs(z) / math.sqrt(2.0))


def two_proportion_p(k1: int, n1: int, k2: int, n2: int) -> float:
    """Two-sided p of the pooled two-proportion z test of k1/n1 against k2/n2; 1.0 when both rates are 0 or 1
    (no spread: the test cannot tell them apart)."""
    if n1 < 1 or n2 < 1:
        raise ValueError(f"two_proportion_p needs episodes on both sides, got n1={n1}, n2={n2}")
    pooled = (k1 + k2) / (n1 + n2)
    se = math.sqrt(pooled * (1.0 - pooled) * (1.0 / n1 + 1.0 / n2))
    if se == 0.0:
        return 1.0
    return normal_two_sided_p((k1 / n1 - k2 / n2) / se)


@dataclass(frozen=True)
class Difference:
    """mean(a) - mean(b) over seeds, its bootstrap interval and two-sided p."""

    effect: float
    low: float
    high: float
    p: float
    n_a: int
    n_b: int

    @property
    def significant(self) -> bool:
        return self.p < SIGNIFICANCE


def bootstrap_difference(a, b, draws: int = BOOTSTRAP_DRAWS, seed: int = BOOTSTRAP_SEED) -> Difference | None:
    """Bootstrap over seeds of mean(a) - mean(b): each draw resamples a's seeds and b's seeds with
    replacement. p: twice the smaller share of draws on either side of zero (at least 1/draws). None when a
    side has fewer than 2 seeds (nothing to resample)."""
    a = [float(v) for v in a if v is not None]
    b = [float(v) for v in b if v is not None]
    if len(a) < 2 or len(b) < 2:
        return None
    rng = random.Random(seed)
    diffs = sorted(sum(rng.choices(a, k=len(a))) / len(a) - sum(rng.choices(b, k=len(b))) / len(b)
                   for _ in range(draws))
    above = sum(d > 0 for d in diffs) + 0.5 * sum(d == 0 for d in diffs)
    p = min(1.0, max(1.0 / draws, 2.0 * min(above, draws - above) / draws))
    tail = (1.0 - CONFIDENCE) / 2.0
    low, high = diffs[int(tail * draws)], diffs[min(draws - 1, int((1.0 - tail) * draws))]
    return Difference(sum(a) / len(a) - sum(b) / len(b), low, high, p, len(a), len(b))


def beyond(other: Interval, ours: Interval) -> bool:
    """other's mean lies above ours's interval (above its mean when ours has no interval)."""
    return other.mean > (ours.high if ours.high is not None else ours.mean)


def not_worse(other: Interval, ours: Interval) -> bool:
    """other's mean at least ours's upper bound: as good as ours on this axis, whatever ours's spread."""
    return other.mean >= (ours.high if ours.high is not None else ours.mean)


def dominates_beyond(other: tuple[Interval, ...], ours: tuple[Interval, ...]) -> bool:
    """`other` beats `ours` beyond ours's intervals: on every axis (higher is better) other's mean is at least
    ours's upper bound, and on one it is above it. With zero-width intervals this is plain Pareto dominance."""
    return all(not_worse(o, u) for o, u in zip(other, ours)) and any(beyond(o, u) for o, u in zip(other, ours))


def collapsed(per_seed: dict, gap: float = COLLAPSE_GAP) -> dict:
    """The seeds of {seed: rate} whose rate is more than `gap` below the median of the seeds (none with
    fewer than 3 seeds: two seeds have no majority to fall away from)."""
    vals = {s: v for s, v in per_seed.items() if v is not None}
    if len(vals) < 3:
        return {}
    median = statistics.median(vals.values())
    return {s: v for s, v in vals.items() if v < median - gap}


def pooled_mean_interval(parts: list[dict], confidence: float = CONFIDENCE) -> dict:
    """The pooled mean and t interval of several groups' {value, low, high, n} (each a t interval over its
    episodes), as if computed on all episodes at once: each group's sd is recovered from its interval's
    half-width, then combined with the spread of the group means (the parallel-variance formula)."""
    n = sum(p["n"] for p in parts)
    mean = sum(p["value"] * p["n"] for p in parts) / n
    if n < 2:
        return {"value": mean, "low": mean, "high": mean, "n": n}
    ss = 0.0
    for p in parts:
        if p["n"] >= 2:
            sd = (p["high"] - p["low"]) / 2.0 * math.sqrt(p["n"]) / t_quantile(confidence, p["n"] - 1)
            ss += (p["n"] - 1) * sd * sd
        ss += p["n"] * (p["value"] - mean) ** 2
    half = t_quantile(confidence, n - 1) * math.sqrt(ss / (n - 1)) / math.sqrt(n)
    return {"value": mean, "low": mean - half, "high": mean + half, "n": n}
