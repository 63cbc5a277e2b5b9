"""Every job's numbers seed by seed, and their intervals with the seed as the unit (stats.py).

Three tables: `progress` lists every job of the study's budget with the seeds finished so far (a study run
in chunks over days: which cells rest on how many runs); `seeds` lists each seed's training and deployment numbers with the seeds that collapsed marked
(so a collapsed seed is seen, not averaged away); `seed_intervals` gives, per job, each training metric as
the mean over seeds with its 95 % t interval, and each deployment rate as the mean of the per-seed rates with
its t interval over seeds beside the pooled rate of all episodes with its Wilson interval, each labelled.
The numbers are read from metrics.json's per_seed and eval.json's per_seed (a one-seed evaluation keeps its
only seed in the level itself).
"""

from __future__ import annotations

from highway_srl.study import stats as S
from highway_srl.study.jobs import BUDGETS, METHOD_LABELS, SCENES, TRAIN_TRAFFIC, study_jobs
from highway_srl.study.results import Result, Results
from highway_srl.study.table import Column, Table, fmt

TRAIN_KEYS = {"T_c": "T_c", "rise_time": "rise_time_steps", "T_r": "T_r", "T_r_rm": "T_r_rm"}
DEPLOY_KEYS = ("C_r", "avg_speed", "R_r", "R_s")
RATES = ("C_r", "R_s")
HEADERS = {"T_c": "T_c", "rise_time": "rise time (steps)", "T_r": "T_r (own reward)", "T_r_rm": "T_r (RM return)",
           "C_r": "C_r", "avg_speed": "avg speed (m/s)", "R_r": "R_r", "R_s": "R_s"}
KINDS = {"T_c": "f3", "rise_time": "f0", "T_r": "f2", "T_r_rm": "f2", "C_r": "pct", "avg_speed": "f2",
         "R_r": "f2", "R_s": "pct"}


def train_seeds(res: Result | None) -> dict[int, dict]:
    """{seed: {episodes, collisions, T_c, rise_time, T_r, T_r_rm}} of a finished job; {} otherwise."""
    if res is None or not res.done:
        return {}
    out = {}
    for seed, m in sorted((res.metrics.get("per_seed") or {}).items(), key=lambda kv: int(kv[0])):
        out[int(seed)] = {"episodes": m.get("episodes"), "collisions": m.get("collisions"),
                          **{name: m.get(key) for name, key in TRAIN_KEYS.items()}}
    return out


def deploy_seeds(res: Result | None, level: str = TRAIN_TRAFFIC) -> dict[int, dict]:
    """{seed: {episodes, C_r, avg_speed, R_r, R_s}} at `level` of a finished job; {} otherwise."""
    if res is None or not res.done or level not in res.evaluation.get("levels", {}):
        return {}
    lv = res.evaluation["levels"][level]
    per_seed = lv.get("per_seed")
    if not per_seed:  # one seed: the level is that seed's
        seed = (res.evaluation.get("trained_seeds") or list(res.job.seeds))[0]
        per_seed = {str(seed): lv}
    out = {}
    for seed, s in sorted(per_seed.items(), key=lambda kv: int(kv[0])):
        out[int(seed)] = {"episodes": s["episodes"], **{k: s[k]["value"] for k in DEPLOY_KEYS if k in s}}
    return out


def summary(res: Result | None, level: str = TRAIN_TRAFFIC) -> dict:
    """Per metric the Interval over seeds; per rate also `RATE_pooled`, the Wilson interval of all episodes;
    seeds / episodes (training) and deploy_seeds / deploy_episodes; collapsed: {metric: {seed: value}}."""
    train, deploy = train_seeds(res), deploy_seeds(res, level)
    out = {"seeds": len(train), "episodes": sum(s["episodes"] or 0 for s in train.values()),
           "deploy_seeds": len(deploy), "deploy_episodes": sum(s["episodes"] for s in deploy.values()),
           "collapsed": {}}
    for name in TRAIN_KEYS:
        out[name] = S.t_interval(s[name] for s in train.values())
    for key in DEPLOY_KEYS:
        out[key] = S.t_interval(s.get(key) for s in deploy.values())
    for key in ("T_c", *RATES):
        out[key] = S.clip_rate(out[key])
    for key in RATES:
        have = [s for s in deploy.values() if s.get(key) is not None]
        out[f"{key}_pooled"] = (S.wilson(sum(round(s[key] * s["episodes"]) for s in have),
                                         sum(s["episodes"] for s in have)) if have else None)
    for name, seeds in (("T_c", train), ("C_r", deploy), ("R_s", deploy)):
        fallen = S.collapsed({seed: s.get(name) for seed, s in seeds.items()})
        if fallen:
            out["collapsed"][name] = fallen
    return out


def interval_text(kind: str, iv: S.Interval | None) -> str:
    """'mean [low, high]' or 'mean (1 seed)'; '–' without a value."""
    if iv is None:
        return "–"
    if iv.low is None:
        return f"{fmt(kind, iv.mean)} (n=1)"
    return f"{fmt(kind, iv.mean)} [{fmt(kind, iv.low)}, {fmt(kind, iv.high)}]"


def _jobs(results: Results):
    """Every finished job, ordered by scene, method and ablation, with its display names."""
    order = {k: i for i, k in enumerate(SCENES)}, {k: i for i, k in enumerate(METHOD_LABELS)}
    for res in sorted(results, key=lambda r: (order[0].get(r.job.scene, 99), order[1].get(r.job.method, 99),
                                              r.job.options)):
        if res.done:
            yield SCENES[res.job.scene].label, res.job.label, res


def seeds_table(results: Results) -> Table:
    """One row per job and seed: training metrics, deployment at level C, and which rates collapsed."""
    rows = []
    for scene, label, res in _jobs(results):
        train, deploy = train_seeds(res), deploy_seeds(res)
        fallen = summary(res)["collapsed"]
        for seed in sorted({*train, *deploy}):
            marks = [name for name, seeds in fallen.items() if seed in seeds]
            rows.append({"scene": scene, "method": label, "job": res.job.id, "seed": seed,
                         **train.get(seed, {}), **{f"deploy_{k}": v for k, v in deploy.get(seed, {}).items()},
                         "collapsed": ", ".join(marks)})
    cols = [Column("scene", "scene"), Column("method", "method"), Column("job", "job"), Column("seed", "seed", "int"),
            Column("episodes", "training episodes", "int"), Column("collisions", "training collisions", "int"),
            *(Column(name, HEADERS[name], KINDS[name]) for name in TRAIN_KEYS),
            Column("deploy_episodes", "deployment episodes (C)", "int"),
            *(Column(f"deploy_{k}", HEADERS[k], KINDS[k]) for k in DEPLOY_KEYS),
            Column("collapsed", "collapsed")]
    shown = [c for c in cols if c.key not in ("job",)]
    return Table("seeds", "Every seed of every finished job", cols, rows, display=Table("", "", shown, rows),
                 notes=[f"Deployment at level {TRAIN_TRAFFIC}. Collapsed: a seed whose rate (T_c, C_r or R_s) is "
                        f"more than {100 * S.COLLAPSE_GAP:.0f} points below the median of its job's seeds (jobs of "
                        "3 seeds or more); its job's means include it and the verdicts name it."])


def intervals_table(results: Results) -> Table:
    """One row per job: training metrics over seeds, deployment rates over seeds and pooled (labelled)."""
    rows = []
    for scene, label, res in _jobs(results):
        s = summary(res)
        row = {"scene": scene, "method": label, "job": res.job.id, "seeds": s["seeds"], "episodes": s["episodes"],
               "deploy_episodes": s["deploy_episodes"]}
        for key in (*TRAIN_KEYS, *DEPLOY_KEYS):
            iv = s[key]
            row[key], row[f"{key}_low"], row[f"{key}_high"] = (iv.mean, iv.low, iv.high) if iv else (None,) * 3
            row[f"{key}_text"] = interval_text(KINDS[key], iv)
        for key in RATES:
            iv = s[f"{key}_pooled"]
            row[f"{key}_pooled"], row[f"{key}_pooled_low"], row[f"{key}_pooled_high"] = (
                (iv.mean, iv.low, iv.high) if iv else (None,) * 3)
            row[f"{key}_pooled_text"] = interval_text("pct", iv)
        rows.append(row)
    keys = [*TRAIN_KEYS, *DEPLOY_KEYS, *(f"{k}_pooled" for k in RATES)]
    cols = [Column("scene", "scene"), Column("method", "method"), Column("job", "job"),
            Column("seeds", "seeds", "int"), Column("episodes", "training episodes", "int"),
            Column("deploy_episodes", "deployment episodes", "int")]
    for key in keys:
        cols += [Column(key, key), Column(f"{key}_low", f"{key} low"), Column(f"{key}_high", f"{key} high")]
    shown = cols[:2] + cols[3:6] + [
        Column(f"{k}_text", f"{HEADERS[k]}, seeds [95% t]") for k in (*TRAIN_KEYS, *DEPLOY_KEYS)] + [
        Column(f"{k}_pooled_text", f"{k}, pooled episodes [95% Wilson]") for k in RATES]
    return Table("seed_intervals", "Every finished job with the seed as the unit: means over seeds [95% interval]",
                 cols, rows, display=Table("", "", shown, rows),
                 notes=["Seeds [95% t]: the mean of the per-seed values with its Student t interval over seeds "
                        "(n = seeds; '(n=1)': one seed, no interval; a rate's interval cut to [0, 1]). Pooled "
                        "episodes [95% Wilson]: all seeds' "
                        f"episodes as one sample, which ignores the spread between runs. Deployment at level "
                        f"{TRAIN_TRAFFIC}."])


def progress_table(results: Results) -> Table | None:
    """One row per job of the study's budget, every profile of it: the seeds finished so far, of the budget's
    seeds, and the chunks that hold them; None for a budget the study code does not know."""
    budget = BUDGETS.get(results.budget)
    if budget is None:
        return None
    done = {r.job.id: r for r in results.every if r.done}
    entries = results.state.get("jobs", {})
    order = {k: i for i, k in enumerate(SCENES)}, {k: i for i, k in enumerate(METHOD_LABELS)}
    plan = sorted(study_jobs(budget), key=lambda j: (budget.profiles.index(j.profile), order[0][j.scene],
                                                     order[1].get(j.method, 99), j.options))
    rows = []
    for job in plan:
        seeds = sorted(done[job.id].job.seeds) if job.id in done else []
        rows.append({"profile": job.profile, "scene": SCENES[job.scene].label, "method": job.label, "job": job.id,
                     "seeds": len(seeds), "target": len(budget.seeds), "finished": " ".join(map(str, seeds)),
                     "chunks": " ".join(entries.get(job.id, {}).get("chunks", [])) if seeds else ""})
    cols = [Column("profile", "profile"), Column("scene", "scene"), Column("method", "method"), Column("job", "job"),
            Column("seeds", "seeds finished", "int"), Column("target", "of", "int"),
            Column("finished", "which"), Column("chunks", "chunks")]
    shown = [c for c in cols if c.key != "job"]
    return Table("progress", f"Progress: every job of the `{results.budget}` budget and its finished seeds", cols,
                 rows, display=Table("", "", shown, rows), notes=[progress_text(rows)])


def progress_text(rows: list[dict]) -> str:
    """Per profile: jobs with a finished seed, with 3 or more, with every seed; seeds finished of all."""
    parts = []
    for profile in dict.fromkeys(r["profile"] for r in rows):
        mine = [r for r in rows if r["profile"] == profile]
        target = mine[0]["target"]
        parts.append(f"{profile} profile: {sum(r['seeds'] > 0 for r in mine)} of {len(mine)} jobs have a finished "
                     f"seed, {sum(r['seeds'] >= 3 for r in mine)} have 3 or more, "
                     f"{sum(r['seeds'] >= target for r in mine)} all {target}; "
                     f"{sum(r['seeds'] for r in mine):,} of {target * len(mine):,} seeds finished")
    return "; ".join(parts) + "."
