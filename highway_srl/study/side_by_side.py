"""Every cell of the paper's Tables 5 and 6 and its multi-lane table, three ways side by side: the paper's
number, ours under the paper's control profile (the reproduction) and ours under each other profile of the
study ("beyond the paper", e.g. `safe`), each with its spread.

The seed is the unit: each cell is the mean over the job's seeds with its 95 % t interval over them and their
number n (seed_tables.summary, the numbers of tables/seed_intervals.md, where the pooled deployment rates
stand beside with their Wilson intervals over episodes). Training metrics are the training's; deployment
metrics (C_r, R_r, R_s, speed, collision rate) level C's.
"""

from __future__ import annotations

from highway_srl.study import paper_numbers as paper
from highway_srl.study import stats as S
from highway_srl.study.seed_tables import interval_text, summary
from highway_srl.study.jobs import (ABLATION_SCENE, ABLATIONS, METHOD_LABELS, MULTILANE_SCENES, OURS, SCENES,
                                    TABLE5_METHODS, TABLE5_SCENES, TRAIN_TRAFFIC)
from highway_srl.study.results import Result, Results
from highway_srl.study.table import Column, Table, fmt
from highway_srl.study.tables import METRIC_LABELS, T5_KINDS

KINDS = {**T5_KINDS, "avg_speed": "f2", "collision_rate": "pct"}
LABELS = {**METRIC_LABELS, "avg_speed": "Ave. speed (m/s)", "collision_rate": "Collision rate"}  # multi-lane's


def cell(res: Result | None, metric: str) -> tuple[float | None, str]:
    """(mean over seeds, Markdown cell 'mean [low, high], n=N' or 'mean (n=1)') of one metric of one job;
    (None, '–') where the job has not finished or has no such number."""
    if res is None or not res.done:
        return None, "–"
    seeds = summary(res, TRAIN_TRAFFIC)
    iv = seeds.get("C_r" if metric == "collision_rate" else metric)
    if iv is None:
        return None, "–"
    if metric == "collision_rate":  # the multi-lane table's: 1 - C_r, its interval flipped
        iv = S.Interval(1.0 - iv.mean, _flip(iv.high), _flip(iv.low), iv.n)
    return iv.mean, interval_text(KINDS[metric], iv) + (f", n={iv.n}" if iv.low is not None else "")


def _flip(rate: float | None) -> float | None:
    return None if rate is None else 1.0 - rate


def _cells() -> list[tuple[str, str, str, str, str, tuple[str, ...], float | None]]:
    """(table, where, metric, method label, scene, options, paper value) of every printed cell."""
    out = []
    for scene in TABLE5_SCENES:
        for metric in paper.TABLE5[scene]:
            metrics = (metric, "T_r_rm") if metric == "T_r" else (metric,)
            for m in TABLE5_METHODS:
                for shown in metrics:
                    value = paper.TABLE5[scene][metric].get(m) if shown == metric else None
                    out.append(("Table 5", SCENES[scene].label, shown, METHOD_LABELS[m], m, scene, (), value))
    for variant, label in (("full", "Full (Ours)"), *ABLATIONS.items()):
        options = () if variant == "full" else (variant,)
        for metric in ("T_c", "T_r", "T_r_rm", "C_r", "R_r"):
            value = paper.TABLE6[variant].get(metric)
            out.append(("Table 6", SCENES[ABLATION_SCENE].label, metric, label, OURS, ABLATION_SCENE, options, value))
    for scene in MULTILANE_SCENES:
        for metric, value in paper.MULTILANE[scene].items():
            out.append(("Multi-lane", SCENES[scene].label, metric, METHOD_LABELS[OURS], OURS, scene, (), value))
    return out


def side_by_side(results: Results) -> Table:
    """One row per printed cell (plus T_r on the RM scale): paper | ours (paper profile) | ours (each
    other profile). `results` is the reproduction's set; its beyond() sets give the other columns."""
    sets = [("paper profile", results)] + [(f"{o.profile} profile", o) for o in results.beyond()]
    rows = []
    for table, where, metric, label, method, scene, options, paper_value in _cells():
        row = {"table": table, "scene": where, "metric": metric, "method": label, "paper": paper_value,
               "paper_text": fmt(KINDS[metric], paper_value)}
        for i, (_, res_set) in enumerate(sets):
            row[f"ours_{i}"], row[f"ours_{i}_text"] = cell(res_set.get(method, scene, options), metric)
        rows.append(row)
    names = [name.split()[0] for name, _ in sets]
    cols = [Column("table", "table"), Column("scene", "scene"), Column("metric", "metric"),
            Column("method", "method"), Column("paper", "paper")]
    cols += [Column(f"ours_{i}", f"ours_{name}") for i, name in enumerate(names)]
    shown = [Column("table", "Table"), Column("scene", "Scene"),
             Column("metric", "Metric", render=lambda r: LABELS.get(r["metric"], r["metric"])),
             Column("method", "Method"), Column("paper_text", "Paper")]
    shown += [Column(f"ours_{i}_text", f"Ours ({name})") for i, (name, _) in enumerate(sets)]
    return Table("side_by_side", "Every cell of Tables 5, 6 and the multi-lane table: the paper, ours under "
                 "the paper's profile, ours beyond it", cols, rows, display=Table("", "", shown, rows),
                 notes=["Each cell: the mean over seeds [its 95% t interval over seeds], n seeds; deployment metrics "
                        "at level C (`tables/seed_intervals.md` gives the pooled rates with their Wilson intervals "
                        "beside). T_r (RM return): the paper's RM reward of the same training episodes, "
                        "one scale for every method (the paper prints only its methods' own T_r). "
                        "'–': not in the paper or not in this study."])


def headline(results: Results) -> Table:
    """MoE-RM-SRL's rows of side_by_side (Table 5 and the multi-lane table): the results page's table."""
    full = side_by_side(results)
    rows = [r for r in full.rows if r["method"] == METHOD_LABELS[OURS]]
    shown = [c for c in full.display.columns if c.key != "method"]
    return Table("headline", "MoE-RM-SRL in every printed cell: the paper, ours under the paper's profile, ours "
                 "beyond it", full.columns, rows, display=Table("", "", shown, rows), notes=full.notes)
