"""A run's training metrics from its episode log (metrics.json): T_c, T_r, the RM return, §4.2's rise time."""

from __future__ import annotations

SMOOTH_EPISODES = 20


def rise_time(steps: list[int], smoothed: list[float], fraction: float = 0.9, from_min: bool = False) -> int:
    """§4.2's rise time: the first of `steps` at which `smoothed` (the smoothed episode return, one value per
    step) reaches `fraction` of its peak. A peak <= 0 (an agent that never earns more than it loses) cannot
    be reached at 90 % of itself from below, so the level is peak - (1 - fraction) |peak|, which is
    fraction x peak for every positive peak. from_min=True is our earlier variant, min + fraction (peak - min)
    of the curve (reported as rise_time_range_steps)."""
    hi, lo = max(smoothed), min(smoothed)
    if from_min:
        level = lo + fraction * (hi - lo)
    else:
        level = fraction * hi if hi >= 0 else (2.0 - fraction) * hi
    return next(step for step, value in zip(steps, smoothed) if value >= level)


def training_metrics(episodes: list[dict], seeds: list[int]) -> dict:
    """T_c, T_r and rise time (§4.2) per seed and averaged.

    T_c: share of training episodes without a collision. T_r: mean return of the last 10% of episodes
    (at least one), in the method's own training reward; T_r_rm: the same mean of the paper's RM return
    (one scale for every method; None for logs written before it existed). Rise time: first env step at which the moving average of returns (20 episodes) reaches
    90 % of its peak (`rise_time`); rise_time_range_steps: where it reaches min + 0.9 (peak - min).
    """
    per_seed = {}
    for seed in seeds:
        eps = [e for e in episodes if e["seed"] == seed]
        if not eps:
            per_seed[seed] = {"episodes": 0, "T_c": None, "T_r": None, "T_r_rm": None, "rise_time_steps": None,
                              "rise_time_range_steps": None}
            continue
        rets = [e["return"] for e in eps]
        tail = rets[-max(1, len(rets) // 10):]
        smooth = [sum(rets[max(0, i - SMOOTH_EPISODES + 1): i + 1]) / len(rets[max(0, i - SMOOTH_EPISODES + 1): i + 1])
                  for i in range(len(rets))]
        steps = [e["step"] for e in eps]
        per_seed[seed] = {
            "episodes": len(eps),
            "T_c": sum(not e["collision"] for e in eps) / len(eps),
            "T_r": sum(tail) / len(tail),
            "T_r_rm": _tail_mean([e.get("rm_return") for e in eps]),
            "rise_time_steps": rise_time(steps, smooth),
            "rise_time_range_steps": rise_time(steps, smooth, from_min=True),
            "collisions": sum(e["collision"] for e in eps),
            "avg_speed": sum(e["avg_speed"] for e in eps) / len(eps),
        }
    mean = {}
    for key in ("T_c", "T_r", "T_r_rm", "rise_time_steps", "rise_time_range_steps", "avg_speed"):
        vals = [m[key] for m in per_seed.values() if m.get(key) is not None]
        mean[key] = sum(vals) / len(vals) if vals else None
    return {"per_seed": {str(k): v for k, v in per_seed.items()}, "mean": mean}


def _tail_mean(values: list) -> float | None:
    """Mean of the last 10 % (at least one) of values; None if any is missing (an old episode log)."""
    if not values or any(v is None for v in values):
        return None
    tail = values[-max(1, len(values) // 10):]
    return sum(tail) / len(tail)
