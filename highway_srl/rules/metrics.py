"""Deployment metrics of §4.2 and Tables 5-6: R_r per step and per episode, C_r, average speed, R_s, with 95% CIs.

R_r (formulas under Tables 5-6), n_max = 320 steps, n_col in {0, 1}:
  expressway (two-lane, multi-lane)  Σ_t (½ v/v* + R*_SV1/4 + R*_SV2/4) - n_max n_col
  merge                              7/10 Σ_t v/v* + 3/10 Σ_t r_merge - n_max n_col
  exit                               1/2 Σ_t v/v* + 3/10 Σ_t Σ_j r_exit,j - n_max n_col
The exit formula's 3/10 is the paper's (the training reward uses 0.25); kept as printed, so an exit episode
can score up to 352, not 320. v/v* is the clipped ratio of reward_machine.speed_ratio.
Table 5's "C_r" is the collision-free rate (the text's "R_c" names the same column): collision_free_rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import torch

from highway_srl.constants import EPISODE_STEPS
from highway_srl.rules.reward_machine import FLAG_ARGUMENT, weighted_sum
from highway_srl.scenarios import scenario_spec

# Student t 97.5% quantiles for 1..30 degrees of freedom (two-sided 95%)
_T975 = (12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.3060, 2.2622, 2.2281, 2.2010, 2.1788, 2.1604,
         2.1448, 2.1314, 2.1199, 2.1098, 2.1009, 2.0930, 2.0860, 2.0796, 2.0739, 2.0687, 2.0639, 2.0595, 2.0555,
         2.0518, 2.0484, 2.0452, 2.0423)


def deployment_step_reward(
    scenario: str,
    speed_ratio: torch.Tensor,
    *,
    r_star: torch.Tensor | None = None,
    r_merge: torch.Tensor | None = None,
    r_exit1: torch.Tensor | None = None,
    r_exit2: torch.Tensor | None = None,
) -> torch.Tensor:
    """One step's term of R_r, (B,): speed_ratio (B,) v/v*; r_star (B, 4) bool (expressway);
    r_merge (B,) 0/1 (merge); r_exit1, r_exit2 (B,) 0/1 (exit)."""
    spec = scenario_spec(scenario)
    given = {"merged": r_merge, "exit1": r_exit1, "exit2": r_exit2}
    if r_star is not None:
        given.update(r_star_sv1=r_star[..., 0], r_star_sv2=r_star[..., 1])
    names = [i for t in spec.deployment_terms for i in t.inputs]
    missing = [i for i in names if given.get(i) is None]
    if any(i.startswith("r_star") for i in missing):
        raise ValueError(f"the {scenario} deployment reward needs r_star (R*_SV1..4)")
    if missing:
        raise ValueError(f"the {scenario} deployment reward needs {' and '.join(FLAG_ARGUMENT[i] for i in names)}")
    return weighted_sum(spec.deployment_main_weight, speed_ratio, spec.deployment_terms, given)


def deployment_episode_reward(
    step_rewards: torch.Tensor,
    collided: torch.Tensor,
    alive: torch.Tensor | None = None,
    n_max: int = EPISODE_STEPS,
) -> torch.Tensor:
    """R_r of each episode, (B,): Σ_t alive_t r_t - n_max n_col. step_rewards (T, B); collided (B,) bool
    (n_col = 1 if the episode had a collision); alive (T, B) bool marks the steps that belong to the episode."""
    r = step_rewards if alive is None else torch.where(alive.bool(), step_rewards, torch.zeros_like(step_rewards))
    return r.sum(0) - float(n_max) * collided.to(r.dtype)


def average_speed(speed_mps: torch.Tensor, alive: torch.Tensor | None = None) -> torch.Tensor:
    """Mean longitudinal ego speed of each episode, (B,), from speeds (T, B) over its alive (T, B) steps."""
    if alive is None:
        return speed_mps.mean(0)
    a = alive.to(speed_mps.dtype)
    return (speed_mps * a).sum(0) / a.sum(0).clamp(min=1.0)


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its confidence interval [low, high] from n samples."""

    value: float
    low: float
    high: float
    n: int

    def __str__(self) -> str:
        return f"{self.value:.4g} [{self.low:.4g}, {self.high:.4g}] (n={self.n})"


def _z(confidence: float) -> float:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    return NormalDist().inv_cdf(0.5 + confidence / 2.0)


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> Estimate:
    """Wilson score interval of a binomial rate successes / n."""
    if n <= 0 or not 0 <= successes <= n:
        raise ValueError(f"need 0 <= successes <= n and n > 0, got successes={successes}, n={n}")
    z = _z(confidence)
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return Estimate(p, max(0.0, centre - half), min(1.0, centre + half), n)


def rate(flags: torch.Tensor, confidence: float = 0.95) -> Estimate:
    """Fraction of True in flags (N,) with its Wilson interval."""
    flags = flags.reshape(-1).bool()
    return wilson_interval(int(flags.sum()), flags.numel(), confidence)


def collision_free_rate(collided: torch.Tensor, confidence: float = 0.95) -> Estimate:
    """C_r (and T_c on training episodes): the fraction of episodes without a collision, Wilson interval."""
    return rate(~collided.reshape(-1).bool(), confidence)


def success_rate(success: torch.Tensor, confidence: float = 0.95) -> Estimate:
    """R_s: merge = reached the stability zone, exit = reached the off-ramp's end; Wilson interval."""
    return rate(success, confidence)


def t_quantile(confidence: float, dof: int) -> float:
    """Two-sided Student t quantile t_{(1+c)/2, dof}: exact for dof 1, 2, a table for 95% up to 30, else the
    Cornish-Fisher expansion (Abramowitz & Stegun 26.7.5), good to 1e-3 from dof 5."""
    if dof < 1:
        raise ValueError(f"need at least 1 degree of freedom, got {dof}")
    p = 0.5 + confidence / 2.0
    if dof == 1:
        return math.tan(math.pi * (p - 0.5))
    if dof == 2:
        return (2 * p - 1) / math.sqrt(2 * p * (1 - p))
    if abs(confidence - 0.95) < 1e-12 and dof <= len(_T975):
        return _T975[dof - 1]
    z = _z(confidence)
    v = float(dof)
    g1 = (z**3 + z) / 4
    g2 = (5 * z**5 + 16 * z**3 + 3 * z) / 96
    g3 = (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / 384
    g4 = (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / 92160
    return z + g1 / v + g2 / v**2 + g3 / v**3 + g4 / v**4


def mean_interval(values: torch.Tensor, confidence: float = 0.95) -> Estimate:
    """Mean of values (N,) with a Student t interval (normal for large N); one value gives a zero-width interval."""
    x = values.reshape(-1).to(torch.float64)
    n = x.numel()
    if n == 0:
        raise ValueError("mean_interval needs at least one value")
    mean = float(x.mean())
    if n == 1:
        return Estimate(mean, mean, mean, 1)
    half = t_quantile(confidence, n - 1) * float(x.std(unbiased=True)) / math.sqrt(n)
    return Estimate(mean, mean - half, mean + half, n)
