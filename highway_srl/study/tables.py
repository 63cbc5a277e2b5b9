"""The study's tables, from the jobs' run folders: each written as CSV (raw numbers) and Markdown.

Every number is read from files the training and evaluation code wrote (metrics.json, eval.json,
episodes.jsonl); nothing is typed in here except the paper's own numbers (paper_numbers.py), shown beside
ours. Spread over runs is the sample standard deviation over seeds (the paper's "10 independent runs");
C_r, R_r, R_s pool every run's episodes, with the 95% intervals of highway_srl.rules.metrics.

One short builder per table of the paper (5, 6, multi-lane, groups 1-3, training) and the cell renderers they
share; the results they read are study/results.py's, the table type and its formats study/table.py's, the
collision tables study/collision_tables.py's.
"""

from __future__ import annotations

from typing import Callable

from highway_srl.study import paper_numbers as paper
from highway_srl.study.jobs import (ABLATION_SCENE, ABLATIONS, GROUP1_METHODS, GROUP2_SCENES, GROUP3_SCENES,
                                           METHOD_LABELS, MULTILANE_SCENES, OURS, SCENES, TABLE5_METHODS,
                                           TABLE5_SCENES, TRAIN_TRAFFIC)
from highway_srl.study.collision_tables import collision_verdicts, collisions
from highway_srl.study.results import Result, Results
from highway_srl.study.table import Column, Table, fmt


def _status(res: Result | None) -> str:
    if res is None:
        return "not in this study"
    return res.status


def _both(kind: str, key: str, paper_key: str) -> Callable[[dict], str]:
    return lambda row: f"{fmt(kind, row.get(key))} / {fmt(kind, row.get(paper_key))}"


def _with_sd(kind: str, key: str) -> Callable[[dict], str]:
    spread = "pp" if kind == "pct" else "sd"

    def render(row: dict) -> str:
        s = fmt(kind, row.get(key))
        if row.get(f"{key}_sd") is not None:
            s += f" {fmt(spread, row[f'{key}_sd'])}"
        return s
    return render


def _with_ci(kind: str, key: str) -> Callable[[dict], str]:
    def render(row: dict) -> str:
        if row.get(key) is None:
            return "–"
        lo, hi = row.get(f"{key}_low"), row.get(f"{key}_high")
        inner = kind if kind != "pct" else "pct"
        return f"{fmt(kind, row[key])} [{fmt(inner, lo)}, {fmt(inner, hi)}]"
    return render


# --------------------------------------------------------------------------------------------- the tables


def group1_deployment(results: Results) -> Table:
    rows = []
    for m in GROUP1_METHODS:
        res = results.get(m, "two-lane")
        if res is None:
            continue
        for level in results.levels:
            d = res.deploy(level) if res.done else None
            rows.append({"method": METHOD_LABELS[m], "method_key": m, "level": level, "status": _status(res),
                         **{k: (d or {}).get(k) for k in ("episodes", "C_r", "C_r_low", "C_r_high", "avg_speed",
                                                          "avg_speed_low", "avg_speed_high", "R_r")}})
    cols = [Column("method", "method"), Column("method_key", "key"), Column("level", "level"),
            Column("status", "status"), Column("episodes", "episodes", "int"),
            Column("C_r", "collision-free rate C_r [95% CI]", render=_with_ci("pct", "C_r")),
            Column("C_r_low", "C_r low", "pct"), Column("C_r_high", "C_r high", "pct"),
            Column("avg_speed", "average speed (m/s) [95% CI]", render=_with_ci("f2", "avg_speed")),
            Column("avg_speed_low", "speed low", "f2"), Column("avg_speed_high", "speed high", "f2"),
            Column("R_r", "R_r", "f1")]
    display = Table("", "", [c for c in cols if c.key in ("method", "level", "status", "episodes", "C_r",
                                                            "avg_speed", "R_r")], rows)
    return Table("group1_deployment", "Group 1: two-lane, trained at level C, deployed at levels "
                 f"{', '.join(results.levels)}", cols, rows,
                 notes=["Episodes pool every seed's episodes at that level; intervals are 95% (Wilson for C_r, "
                        "Student t for speed)."], display=display)


def _runs(results: Results, scenes, methods):
    """(scene, method key, Result) of every job the results hold, scene by scene, in the methods' order."""
    for scene in scenes:
        for m in methods:
            res = results.get(m, scene)
            if res is not None:
                yield scene, m, res


def _runs_rows(results: Results, scenes, methods) -> list[dict]:
    rows = []
    for scene, m, res in _runs(results, scenes, methods):
        d = (res.deploy(TRAIN_TRAFFIC) if res.done else None) or {}
        t = (res.train() if res.done else None) or {}
        row = {"scene": SCENES[scene].label, "scene_key": scene, "method": METHOD_LABELS[m], "method_key": m,
               "status": _status(res), "runs": d.get("runs"), "episodes_per_run": d.get("episodes_per_run"),
               "T_c": t.get("T_c"), "T_c_sd": t.get("T_c_sd")}
        for k in ("C_r", "collision_rate", "avg_speed", "R_r", "R_s"):
            row[k], row[f"{k}_sd"] = d.get(k), d.get(f"{k}_sd")
        row["adv_triggers"], row["adv_cut_ins"] = d.get("adv_triggers"), d.get("adv_cut_ins")
        rows.append(row)
    return rows


def _runs_table(name: str, title: str, rows: list[dict]) -> Table:
    keys = ("C_r", "collision_rate", "avg_speed", "R_r", "R_s")
    kinds = {"C_r": "pct", "collision_rate": "pct", "avg_speed": "f2", "R_r": "f2", "R_s": "pct"}
    headers = {"C_r": "C_r", "collision_rate": "collision rate", "avg_speed": "avg speed (m/s)", "R_r": "R_r",
               "R_s": "R_s"}
    cols = [Column("scene", "scene"), Column("scene_key", "scene key"), Column("method", "method"),
            Column("method_key", "method key"), Column("status", "status"), Column("runs", "runs", "int"),
            Column("episodes_per_run", "episodes/run", "int"), Column("T_c", "T_c", "f3"),
            Column("T_c_sd", "T_c sd", "f3")]
    for k in keys:
        cols += [Column(k, headers[k], kinds[k]), Column(f"{k}_sd", f"{headers[k]} sd", kinds[k])]
    shown = [Column("scene", "scene"), Column("method", "method"), Column("status", "status"),
             Column("runs", "runs", "int"), Column("episodes_per_run", "episodes/run", "int"),
             Column("T_c", "T_c", render=_with_sd("f3", "T_c"))]
    shown += [Column(k, f"{headers[k]} (± sd over runs)", render=_with_sd(kinds[k], k))
              for k in keys if k != "collision_rate"]
    adversary = [Column("adv_triggers", "adversary triggers / episode", "f2"),
                 Column("adv_cut_ins", "cut-ins / episode", "f2")]
    return Table(name, title, cols + adversary, rows, display=Table("", "", shown + adversary, rows),
                 notes=["Mean over all runs' episodes; ± is the standard deviation over runs (seeds), shown when "
                        "there are two or more. R_s: merging and exiting only. Adversary triggers / cut-ins: "
                        "group-3 trigger draws and forced lane changes per deployment episode (adversarial "
                        "scenes, our simulator)."])


def group2(results: Results) -> Table:
    methods = tuple(dict.fromkeys((OURS, *TABLE5_METHODS)))
    return _runs_table("group2", "Group 2: multi-lane (normal, adversarial), merging and exiting at level C",
                       _runs_rows(results, GROUP2_SCENES, methods))


def group3(results: Results) -> Table:
    methods = tuple(dict.fromkeys((OURS, *TABLE5_METHODS)))
    return _runs_table("group3", "Group 3: adversarial two-lane, merging and exiting at level C",
                       _runs_rows(results, GROUP3_SCENES, methods))


def multilane(results: Results) -> Table:
    rows = []
    names = {"avg_speed": ("Ave. speed (m/s)", "f2"), "collision_rate": ("Collision rate", "pct"),
             "R_r": ("Ave. reward", "f2")}
    deploys = {}
    for scene in MULTILANE_SCENES:
        res = results.get(OURS, scene)
        deploys[scene] = (res.deploy(TRAIN_TRAFFIC) if res is not None and res.done else None) or {}
    for metric, (label, kind) in names.items():
        row = {"metric": label, "metric_key": metric, "kind": kind}
        for scene, col in (("multi-lane", "normal"), ("adv-multi-lane", "adversarial")):
            row[col] = deploys[scene].get(metric)
            row[f"{col}_sd"] = deploys[scene].get(f"{metric}_sd")
            row[f"{col}_paper"] = paper.MULTILANE[scene][metric]
        rows.append(row)
    cols = [Column("metric", "metric"), Column("metric_key", "key")]
    for col in ("normal", "adversarial"):
        cols += [Column(col, col), Column(f"{col}_sd", f"{col} sd"), Column(f"{col}_paper", f"{col} (paper)")]

    def cell(col: str) -> Callable[[dict], str]:
        def render(row):
            s = fmt(row["kind"], row.get(col))
            if row.get(f"{col}_sd") is not None:
                s += " " + fmt("pp" if row["kind"] == "pct" else "sd", row[f"{col}_sd"])
            return f"{s} / {fmt(row['kind'], row[f'{col}_paper'])}"
        return render
    shown = [Column("metric", "metric"), Column("normal", "normal: ours / paper", render=cell("normal")),
             Column("adversarial", "adversarial: ours / paper", render=cell("adversarial"))]
    return Table("multilane", "Multi-lane, MoE-RM-SRL (the paper's multi-lane table)", cols, rows,
                 display=Table("", "", shown, rows),
                 notes=["Collision rate = 1 - C_r; ± is the standard deviation over runs."])


T5_KINDS = {"T_c": "f3", "T_r": "f2", "T_r_rm": "f2", "C_r": "pct", "R_r": "f2", "R_s": "pct"}
# T_r twice (§4.2 "on one scale"): each method's own training return, and the paper's RM return of the same
# episodes, which every method is scored with; the paper prints one T_r (its methods' own returns)
METRIC_LABELS = {"T_r": "T_r (own reward)", "T_r_rm": "T_r (RM return)"}


def _with_rm_return(metrics: list[str]) -> list[str]:
    """The paper's metric rows with T_r_rm after T_r."""
    out = []
    for metric in metrics:
        out.append(metric)
        if metric == "T_r":
            out.append("T_r_rm")
    return out


def table5(results: Results) -> Table:
    rows, wide = [], []
    for scene in TABLE5_SCENES:
        res_of = {m: results.get(m, scene) for m in TABLE5_METHODS}
        metrics = _with_rm_return(list(paper.TABLE5[scene]))
        for metric in metrics:
            wrow = {"scene": SCENES[scene].label, "metric": METRIC_LABELS.get(metric, metric)}
            for m in TABLE5_METHODS:
                res = res_of[m]
                ours, spread = _t5_value(res, metric)
                paper_value = paper.TABLE5[scene].get(metric, {}).get(m)
                rows.append({"scene": SCENES[scene].label, "scene_key": scene, "metric": metric,
                             "method": METHOD_LABELS[m], "method_key": m, "status": _status(res), "ours": ours,
                             "ours_sd": spread, "paper": paper_value})
                wrow[m] = f"{fmt(T5_KINDS[metric], ours)} / {fmt(T5_KINDS[metric], paper_value)}"
            wide.append(wrow)
    cols = [Column("scene", "scene"), Column("scene_key", "scene key"), Column("metric", "metric"),
            Column("method", "method"), Column("method_key", "method key"), Column("status", "status"),
            Column("ours", "ours"), Column("ours_sd", "ours sd over runs"), Column("paper", "paper")]
    shown = [Column("scene", "Scene"), Column("metric", "Metric")] + [
        Column(m, f"{METHOD_LABELS[m] if m != OURS else 'Ours'} (ours / paper)") for m in TABLE5_METHODS]
    return Table("table5", "Table 5: comparison on the six scenes (ours / paper)", cols, rows,
                 display=Table("", "", shown, wide),
                 notes=["T_c training collision-free rate, T_r final training return (last 10% of episodes) in "
                        "the method's own training reward, T_r (RM return) the paper's RM reward of the same "
                        "episodes (one scale for every method; the paper prints only the first), "
                        "C_r deployment collision-free rate, R_r deployment reward, R_s success rate; means over "
                        "seeds / pooled episodes at level C. '–': no result (see the report's job list)."])


def _t5_value(res: Result | None, metric: str) -> tuple[float | None, float | None]:
    if res is None or not res.done:
        return None, None
    if metric in ("T_c", "T_r", "T_r_rm"):
        t = res.train()
        return t[metric], t[f"{metric}_sd"]
    d = res.deploy(TRAIN_TRAFFIC) or {}
    return d.get(metric), d.get(f"{metric}_sd")


def table6(results: Results) -> Table:
    rows = []
    for variant, label in (("full", "Full (Ours)"), *ABLATIONS.items()):
        res = results.get(OURS, ABLATION_SCENE, () if variant == "full" else (variant,))
        row = {"variant": label, "variant_key": variant, "status": _status(res)}
        for metric in ("T_c", "T_r", "T_r_rm", "C_r", "R_r"):
            row[metric], row[f"{metric}_sd"] = _t5_value(res, metric)
            row[f"{metric}_paper"] = paper.TABLE6[variant].get(metric)
        rows.append(row)
    cols = [Column("variant", "variant"), Column("variant_key", "key"), Column("status", "status")]
    for metric in ("T_c", "T_r", "T_r_rm", "C_r", "R_r"):
        cols += [Column(metric, metric), Column(f"{metric}_sd", f"{metric} sd"),
                 Column(f"{metric}_paper", f"{metric} (paper)")]
    shown = [Column("variant", "Variant"), Column("status", "status")] + [
        Column(m, f"{METRIC_LABELS.get(m, m)} (ours / paper)", render=_both(T5_KINDS[m], m, f"{m}_paper"))
        for m in ("T_c", "T_r", "T_r_rm", "C_r", "R_r")]
    return Table("table6", "Table 6: ablation on adversarial two-lane (ours / paper)", cols, rows,
                 display=Table("", "", shown, rows))


def training(results: Results) -> Table:
    """T_c, rise time and T_r of every non-ablation run: the training Pareto figure's data."""
    rows = []
    for scene, m, res in _runs(results, SCENES, METHOD_LABELS):
        t = (res.train() if res.done else None) or {}
        rows.append({"scene": SCENES[scene].label, "scene_key": scene, "method": METHOD_LABELS[m],
                     "method_key": m, "status": _status(res), "seeds": t.get("seeds"),
                     "episodes": t.get("episodes"), "collisions": t.get("collisions"),
                     "T_c": t.get("T_c"), "T_c_sd": t.get("T_c_sd"), "rise_time": t.get("rise_time"),
                     "rise_time_sd": t.get("rise_time_sd"), "T_r": t.get("T_r"), "T_r_sd": t.get("T_r_sd"),
                     "T_r_rm": t.get("T_r_rm"), "T_r_rm_sd": t.get("T_r_rm_sd")})
    cols = [Column("scene", "scene"), Column("scene_key", "scene key"), Column("method", "method"),
            Column("method_key", "method key"), Column("status", "status"), Column("seeds", "seeds", "int"),
            Column("episodes", "training episodes", "int"), Column("collisions", "training collisions", "int"),
            Column("T_c", "T_c", "f3"), Column("T_c_sd", "T_c sd", "f3"),
            Column("rise_time", "rise time (steps)", "int"), Column("rise_time_sd", "rise time sd", "f0"),
            Column("T_r", "T_r (own reward)", "f2"), Column("T_r_sd", "T_r sd", "f2"),
            Column("T_r_rm", "T_r (RM return)", "f2"), Column("T_r_rm_sd", "T_r (RM return) sd", "f2")]
    shown = [c for c in cols if c.key in ("scene", "method", "status", "seeds", "episodes", "collisions")] + [
        Column("T_c", "T_c", render=_with_sd("f3", "T_c")), Column("rise_time", "rise time (steps)", "int"),
        Column("T_r", "T_r (own reward)", render=_with_sd("f2", "T_r")),
        Column("T_r_rm", "T_r (RM return)", render=_with_sd("f2", "T_r_rm"))]
    return Table("training_pareto", "Training: collision-free rate T_c against rise time", cols, rows,
                 display=Table("", "", shown, rows),
                 notes=["Rise time: env steps per seed until the 20-episode moving average of the return first "
                        "reaches 90% of its range (highway_srl.experiments.train.training_metrics)."])


CURVE_BINS = 20


def _curve_rows(scene: str, m: str, res: Result) -> list[dict]:
    """One finished job's training curve: CURVE_BINS rows of (return, cumulative collisions) over its seeds."""
    import numpy as np

    episodes = res.episodes()
    steps = res.job.steps
    edges = np.linspace(0, steps, CURVE_BINS + 1)
    seeds = sorted({e["seed"] for e in episodes}) or list(res.job.seeds)
    ret = np.full((len(seeds), CURVE_BINS), np.nan)
    col = np.zeros((len(seeds), CURVE_BINS))
    for i, seed in enumerate(seeds):
        eps = [e for e in episodes if e["seed"] == seed]
        at = np.array([e["step"] for e in eps], dtype=float)
        r = np.array([e["return"] for e in eps], dtype=float)
        c = np.array([bool(e["collision"]) for e in eps], dtype=float)
        idx = np.clip(np.searchsorted(edges, at, side="left") - 1, 0, CURVE_BINS - 1)
        for b in range(CURVE_BINS):
            sel = idx == b
            if sel.any():
                ret[i, b] = r[sel].mean()
            col[i, b] = c[idx <= b].sum()
    scene_rows = []
    for b in range(CURVE_BINS):
        have = ret[:, b][~np.isnan(ret[:, b])]
        row = {"scene": SCENES[scene].label, "scene_key": scene, "method": METHOD_LABELS[m], "method_key": m,
               "step": float(edges[b + 1]), "seeds": len(seeds), "seeds_with_episodes": int(have.size),
               "return_mean": float(have.mean()) if have.size else None,
               "return_sd": float(have.std(ddof=1)) if have.size >= 2 else None,
               "collisions_mean": float(col[:, b].mean()),
               "collisions_sd": float(col[:, b].std(ddof=1)) if len(seeds) >= 2 else None}
        scene_rows.append(row)
    return scene_rows


def training_curves(results: Results) -> tuple[Table, dict]:
    """Return and cumulative collisions against env steps, per scene and method: mean and sd over seeds.

    Returns the CSV/Markdown table and {scene: {method label: rows}} for the figures.
    """
    rows, series = [], {}
    for scene, m, res in _runs(results, SCENES, METHOD_LABELS):
        if res.done:
            scene_rows = _curve_rows(scene, m, res)
            rows += scene_rows
            series.setdefault(scene, {})[METHOD_LABELS[m]] = scene_rows
    cols = [Column("scene", "scene"), Column("scene_key", "scene key"), Column("method", "method"),
            Column("method_key", "method key"), Column("step", "env steps", "int"), Column("seeds", "seeds", "int"),
            Column("seeds_with_episodes", "seeds with episodes", "int"),
            Column("return_mean", "return", "f2"), Column("return_sd", "return sd", "f2"),
            Column("collisions_mean", "cumulative collisions", "f2"), Column("collisions_sd", "collisions sd", "f2")]
    summary = []
    for scene, by_method in series.items():
        for label, srows in by_method.items():
            have = [r for r in srows if r["return_mean"] is not None]
            summary.append({"scene": SCENES[scene].label, "method": label, "seeds": srows[-1]["seeds"],
                            "first_return": have[0]["return_mean"] if have else None,
                            "last_return": have[-1]["return_mean"] if have else None,
                            "collisions": srows[-1]["collisions_mean"]})
    shown = [Column("scene", "scene"), Column("method", "method"), Column("seeds", "seeds", "int"),
             Column("first_return", "return, first bin", "f2"), Column("last_return", "return, last bin", "f2"),
             Column("collisions", "training collisions per seed (mean)", "f2")]
    table = Table("training_curves", "Training curves: return and cumulative collisions against env steps", cols,
                  rows, display=Table("", "", shown, summary),
                  notes=[f"The CSV has {CURVE_BINS} bins of env steps per scene and method; return: mean of the "
                         "episodes ending in the bin; collisions: cumulative count; mean and sd over seeds."])
    return table, series


REPORT_TABLES = ("table5", "table6", "group1_deployment", "group2", "multilane", "group3", "collisions",
                 "collision_verdicts")


def all_tables(results: Results) -> dict[str, Table]:
    """The reproduction's tables, then each other profile's as NAME_PROFILE, titled "Beyond the paper"."""
    out = {t.name: t for t in (group1_deployment(results), group2(results), multilane(results), group3(results),
                               table5(results), table6(results), collisions(results),
                               collision_verdicts(results))}
    for other in results.beyond():
        for t in (group1_deployment(other), group2(other), multilane(other), group3(other), table5(other),
                  table6(other), training(other), collisions(other), collision_verdicts(other)):
            t.name = f"{t.name}_{other.profile}"
            t.title = f"Beyond the paper ({other.profile} profile): {t.title}"
            out[t.name] = t
    return out
