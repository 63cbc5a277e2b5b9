"""The paper's published numbers, typed in for side-by-side comparison with ours.

Table 5 ("Comprehensive comparison"), Table 6 ("Ablation results (adv. two-lane)") and the multi-lane
table, exactly as printed. Percentages are stored as fractions (C_r 89.1% -> 0.891) so they compare
directly with our rates; T_c is printed as a fraction already. Scene and method keys are the study's
(`highway_srl.study.jobs.SCENES` / `METHOD_LABELS`).
"""

from __future__ import annotations

# Table 5: scene -> metric -> method -> value. R_s exists for merging and exiting only.
_T5_METHODS = ("et-rl", "mp-rl", "sr-rl", "rl", "lm-rl", "moe-rm-srl")  # the printed column order


def _row(*values: float) -> dict[str, float]:
    return dict(zip(_T5_METHODS, values, strict=True))


TABLE5: dict[str, dict[str, dict[str, float]]] = {
    "two-lane": {
        "T_c": _row(0.914, 0.998, 1.000, 0.000, 0.895, 1.000),
        "T_r": _row(97.31, 228.64, 229.10, -165.38, 162.18, 228.19),
        "C_r": _row(0.891, 1.00, 1.00, 0.086, 0.969, 1.00),
        "R_r": _row(90.42, 214.00, 213.07, -161.38, 168.51, 217.89),
    },
    "merge": {
        "T_c": _row(0.942, 0.999, 0.998, 0.000, 0.846, 1.000),
        "T_r": _row(149.26, 224.33, 232.43, -138.55, 103.90, 232.81),
        "C_r": _row(0.482, 1.00, 1.00, 0.973, 0.571, 1.00),
        "R_r": _row(-65.04, 207.74, 238.45, 182.49, 20.49, 240.42),
        "R_s": _row(0.893, 0.862, 0.870, 0.593, 0.571, 0.898),
    },
    "exit": {
        "T_c": _row(0.819, 0.994, 0.996, 0.000, 0.186, 1.000),
        "T_r": _row(35.03, 92.35, 93.96, -80.89, -12.87, 94.83),
        "C_r": _row(0.978, 0.994, 0.997, 0.621, 0.400, 1.00),
        "R_r": _row(35.70, 58.90, 51.42, -39.44, -78.08, 72.52),
        "R_s": _row(0.0010, 0.502, 0.423, 0.000, 0.000, 0.802),
    },
    "adv-two-lane": {
        "T_c": _row(0.469, 0.989, 0.755, 0.000, 0.792, 1.000),
        "T_r": _row(-214.78, 82.21, -56.09, -236.97, -152.71, 144.00),
        "C_r": _row(0.781, 0.875, 0.380, 0.050, 0.379, 0.929),
        "R_r": _row(-57.41, 100.23, -72.05, -238.13, -68.97, 155.03),
    },
    "adv-merge": {
        "T_c": _row(0.000, 0.938, 0.364, 0.047, 0.057, 1.000),
        "T_r": _row(72.68, 85.30, 90.00, 47.50, 14.17, 95.39),
        "C_r": _row(0.853, 0.885, 0.897, 0.620, 0.487, 0.954),
        "R_r": _row(43.08, 92.83, 94.62, 98.51, 27.83, 113.58),
        "R_s": _row(0.938, 0.971, 0.956, 0.737, 0.817, 0.942),
    },
    "adv-exit": {
        "T_c": _row(0.918, 0.834, 0.199, 0.000, 0.431, 1.000),
        "T_r": _row(-7.90, 19.32, -62.95, -80.89, -33.86, 29.74),
        "C_r": _row(0.751, 0.858, 0.666, 0.275, 0.642, 0.927),
        "R_r": _row(6.44, 21.18, -0.09, -91.18, -36.82, 35.40),
        "R_s": _row(0.101, 0.476, 0.534, 0.174, 0.001, 0.815),
    },
}

# Table 6 (adv. two-lane): variant -> metric -> value. "full" is MoE-RM-SRL itself.
TABLE6: dict[str, dict[str, float]] = {
    "full": {"T_c": 1.0, "T_r": 144.0, "C_r": 0.929, "R_r": 155.03},
    "no_mapping": {"T_c": 0.0, "T_r": -100.79, "C_r": 0.377, "R_r": -82.52},
    "no_moe": {"T_c": 0.743, "T_r": 25.22, "C_r": 0.388, "R_r": 25.75},
    "no_rm": {"T_c": 0.983, "T_r": 164.00, "C_r": 0.871, "R_r": 70.03},
}

# Multi-lane table (MoE-RM-SRL only): scene -> metric -> value. The paper reports a collision rate here,
# not a collision-free rate: collision_rate = 1 - C_r.
MULTILANE: dict[str, dict[str, float]] = {
    "multi-lane": {"avg_speed": 7.34, "collision_rate": 0.0, "R_r": 250.97},
    "adv-multi-lane": {"avg_speed": 6.69, "collision_rate": 0.134, "R_r": 143.64},
}

# What the paper's text says about training and evaluation budgets (§4.1, §4.3, Table 2).
PAPER_BUDGET = {"steps": 500_000, "runs": 10, "episodes": 100, "batch_size": 256}
