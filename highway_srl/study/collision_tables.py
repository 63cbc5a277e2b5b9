"""The study's collision tables: what the deployment collisions were (evaluate's census and decision trace),
and every collision in training and deployment split by the ego-avoidable verdict (rules/avoidable.py).
Read from the jobs' metrics.json and eval.json (study/results.py); the table type is study/table.py's."""

from __future__ import annotations

from highway_srl.experiments.collisions import CREEP, FORBIDDEN, LANE_CHANGE_CYCLE, OTHER
from highway_srl.study.jobs import METHOD_LABELS, SCENES, TRAIN_TRAFFIC
from highway_srl.study.results import Result, Results
from highway_srl.study.table import Column, Table, fmt

COLLISION_KINDS = ("front", "rear", "side", "road")
DECISION_COLUMNS = {"decision_forbidden": FORBIDDEN, "decision_lane_change_r1": LANE_CHANGE_CYCLE,
                    "decision_creep": CREEP, "decision_other": OTHER}


def _finished(results: Results):
    """Every finished job, ordered by scene, method and ablation."""
    order = {k: i for i, k in enumerate(SCENES)}, {k: i for i, k in enumerate(METHOD_LABELS)}
    for res in sorted(results, key=lambda r: (order[0].get(r.job.scene, 99), order[1].get(r.job.method, 99),
                                              r.job.options)):
        if res.done:
            yield res


def collisions(results: Results) -> Table:
    """What the deployment collisions were, per job and level that had any (evaluate's census)."""
    rows = []
    for res in _finished(results):
        for level, lv in res.evaluation["levels"].items():
            c = lv.get("collisions")
            if not c or not c["collisions"]:  # none, or an evaluation written before the census
                continue
            kinds, decided = c["by_kind"], c.get("by_decision")  # by_decision: evaluations since the trace
            rows.append({"scene": SCENES[res.job.scene].label, "scene_key": res.job.scene, "method": res.job.label,
                         "method_key": res.job.method, "level": level, "episodes": lv["episodes"],
                         "collisions": c["collisions"], **{k: kinds.get(k, 0) for k in COLLISION_KINDS},
                         **{k: c.get(k) for k in ("while_ego_changing", "sv_changing", "sv_forced_cut_in",
                                                  "mean_ego_speed", "mean_sv_speed")},
                         **{key: (decided or {}).get(name) for key, name in DECISION_COLUMNS.items()}})
    cols = [Column("scene", "scene"), Column("scene_key", "scene key"), Column("method", "method"),
            Column("method_key", "method key"), Column("level", "level"), Column("episodes", "episodes", "int"),
            Column("collisions", "collisions", "int"),
            Column("front", "ego into the car ahead", "int"), Column("rear", "hit from behind", "int"),
            Column("side", "side contact", "int"), Column("road", "road (lane end, barrier, edge)", "int"),
            Column("while_ego_changing", "while the ego changed lanes", "int"),
            Column("sv_changing", "SV changing lanes", "int"),
            Column("sv_forced_cut_in", "SV in a forced cut-in", "int"),
            Column("mean_ego_speed", "ego speed at contact (m/s)", "f2"),
            Column("mean_sv_speed", "SV speed at contact (m/s)", "f2"),
            *(Column(key, f"decisions: {name}", "int") for key, name in DECISION_COLUMNS.items())]
    decisions = Column("decisions", "through which decision: forbidden / lane change at R*1 = 0 / creep / other",
                       render=lambda r: " / ".join("-" if r[k] is None else str(r[k]) for k in DECISION_COLUMNS))
    shown = [c for c in cols if c.key not in ("scene_key", "method_key", *DECISION_COLUMNS)] + [decisions]
    return Table("collisions", "What the deployment collisions were", cols, rows, display=Table("", "", shown, rows),
                 notes=["Every deployment collision of the ego, read from the state the colliding step left "
                        "(experiments/collisions.py; docs/paper-notes.md, 'Collision census'). Jobs and levels "
                        "without a collision, and evaluations written before the census, are not listed.",
                        "Through which decision (the decision trace, docs/paper-notes.md): in the last 8 "
                        "decisions, an action the method's safe mask forbade; else a lane change allowed and "
                        "executed while R*1 = 0 (the printed mappings hold the speed through it); else Faster "
                        "or Idle allowed at a bumper gap under 0.5 m (creep); else other. '-': an evaluation "
                        "written before the trace."])


VERDICTS = ("collisions", "ego_avoidable", "unavoidable", "not_judged")


def training_verdicts(res: Result) -> dict:
    """A finished job's training collisions split by the ego-avoidable verdict (metrics.json's
    collision_verdicts); a run trained before the verdicts: its count alone, the split None."""
    verdicts = (res.metrics.get("collision_verdicts") or {}).get("all")
    if verdicts is not None:
        return {key: verdicts[key] for key in VERDICTS}
    return {**dict.fromkeys(VERDICTS), "collisions": res.train()["collisions"]}


def deployment_verdicts(level: dict) -> dict:
    """One evaluated level's collisions split by the verdict (eval.json's census); an evaluation written
    before the verdicts: its count alone (before the census too: from C_r), the split None."""
    census = level.get("collisions") or {}
    count = census.get("collisions", round((1.0 - level["C_r"]["value"]) * level["episodes"]))
    if "ego_avoidable" not in census:
        return {**dict.fromkeys(VERDICTS), "collisions": count}
    judged = census["ego_avoidable"] + census["unavoidable"]
    return {"collisions": count, "ego_avoidable": census["ego_avoidable"], "unavoidable": census["unavoidable"],
            "not_judged": count - judged}


def _verdict_text(row: dict | None) -> str:
    """'collisions: ego-avoidable / unavoidable / not judged'; '' where the job has no such phase."""
    if row is None:
        return ""
    return f"{fmt('int', row['collisions'])}: " + " / ".join(fmt("int", row[k]) for k in VERDICTS[1:])


def collision_verdicts(results: Results) -> Table:
    """Every finished job's collisions in training and at each deployment level, split into those the ego
    could have avoided and those it could not (rules.avoidable): one CSV row per job and phase, one
    Markdown row per job with a cell per phase."""
    rows, wide, levels = [], [], set()
    for res in _finished(results):
        job = {"scene": SCENES[res.job.scene].label, "scene_key": res.job.scene, "method": res.job.label,
               "method_key": res.job.method}
        training = training_verdicts(res)
        rows.append({**job, "phase": "training", "level": TRAIN_TRAFFIC, "episodes": res.train()["episodes"],
                     **training})
        cells = {**job, "training": training}
        for level, lv in res.evaluation["levels"].items():
            cells[f"deploy_{level}"] = deployment_verdicts(lv)
            rows.append({**job, "phase": "deployment", "level": level, "episodes": lv["episodes"],
                         **cells[f"deploy_{level}"]})
            levels.add(level)
        wide.append(cells)
    cols = [Column("scene", "scene"), Column("scene_key", "scene key"), Column("method", "method"),
            Column("method_key", "method key"), Column("phase", "phase"), Column("level", "level"),
            Column("episodes", "episodes", "int"), Column("collisions", "collisions", "int"),
            Column("ego_avoidable", "ego-avoidable", "int"), Column("unavoidable", "unavoidable", "int"),
            Column("not_judged", "not judged", "int")]
    split = "collisions: ego-avoidable / unavoidable / not judged"
    shown = [Column("scene", "scene"), Column("method", "method"),
             Column("training", f"training ({split})", render=lambda r: _verdict_text(r.get("training")))] + [
        Column(f"deploy_{level}", f"deployment at {level}",
               render=lambda r, key=f"deploy_{level}": _verdict_text(r.get(key)))
        for level in sorted(levels)]  # the traffic levels A-E, lightest first
    return Table("collision_verdicts", "Collisions the ego could have avoided, in training and deployment",
                 cols, rows, display=Table("", "", shown, wide),
                 notes=["Each collision of the ego judged from the decisions before it (rules/avoidable.py; "
                        "docs/paper-notes.md, 'Ego-avoidable collisions'): ego-avoidable if some action within the "
                        "ego's limits would have prevented it while every other car kept to its own (RSS's "
                        "responsibility rule; doubtful cases count as avoidable). Not judged: training collisions "
                        "of a loop that reads no state back (the static step). '–': a run trained or evaluated "
                        "before the verdicts were recorded, its count alone. An empty cell: the job was not "
                        "deployed at that level."])
