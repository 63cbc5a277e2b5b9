"""A study's job results, read from its study.json and the jobs' run folders (metrics.json, eval.json,
episodes.jsonl), each file checked as it is read: what the tables, figures and report are made of."""

from __future__ import annotations

import json
import math
import os
import statistics
from dataclasses import dataclass, field
from pathlib import Path

from highway_srl.constants import TRAFFIC_LEVELS
from highway_srl.experiments.records import check_fields, check_lists, read_episode_log, read_eval, read_metrics
from highway_srl.experiments.runs import read_json
from highway_srl.study.jobs import METHOD_LABELS, SCENES, TRAIN_TRAFFIC, Job


@dataclass
class Result:
    """One job of the study as found on disk."""

    job: Job
    status: str  # done | failed | unavailable | pending
    message: str | None
    folder: Path
    metrics: dict | None = None
    evaluation: dict | None = None

    @property
    def done(self) -> bool:
        return self.status == "done" and self.metrics is not None and self.evaluation is not None

    def train(self) -> dict | None:
        """T_c, T_r (own training reward), T_r_rm (the paper's RM return, one scale for every method), rise
        time (means over seeds) and their spread; None if not trained."""
        if self.metrics is None:
            return None
        per_seed = list(self.metrics.get("per_seed", {}).values())
        out = {"seeds": len(per_seed), "episodes": sum(s.get("episodes") or 0 for s in per_seed),
               "collisions": sum(s.get("collisions") or 0 for s in per_seed)}
        for key, name in (("T_c", "T_c"), ("T_r", "T_r"), ("T_r_rm", "T_r_rm"), ("rise_time_steps", "rise_time")):
            out[name] = self.metrics.get("mean", {}).get(key)
            out[f"{name}_sd"] = sd([s.get(key) for s in per_seed])
        return out

    def deploy(self, level: str = TRAIN_TRAFFIC) -> dict | None:
        """Deployment metrics at one traffic level: pooled values, 95% intervals, spread over runs."""
        if self.evaluation is None or level not in self.evaluation.get("levels", {}):
            return None
        lv = self.evaluation["levels"][level]
        per_seed = list((lv.get("per_seed") or {}).values())
        out = {"episodes": lv["episodes"], "runs": max(1, len(per_seed)),
               "episodes_per_run": self.evaluation.get("episodes_per_level")}
        for key in ("C_r", "avg_speed", "R_r", "R_s"):
            if key not in lv:
                continue
            out[key], out[f"{key}_low"], out[f"{key}_high"] = lv[key]["value"], lv[key]["low"], lv[key]["high"]
            out[f"{key}_sd"] = sd([s[key]["value"] for s in per_seed])
        out["collision_rate"] = 1.0 - out["C_r"]
        out["collision_rate_sd"] = out["C_r_sd"]
        adversary = lv.get("adversary") or {}  # group 3: per episode, pooled over runs
        out["adv_triggers"] = adversary.get("triggers_per_episode")
        out["adv_cut_ins"] = adversary.get("cut_ins_per_episode")
        return out

    def episodes(self) -> list[dict]:
        return job_episodes(self.folder, self.job)


def job_episodes(folder: Path, job: Job) -> list[dict]:
    """A job's training episodes (episodes.jsonl), every row checked (records.read_episode_log): a damaged
    row is a one-line error naming the file and line. The text after the last newline, a row a running job
    is appending, is left out while the job runs; once it finished (metrics.json) such a line is damage."""
    from highway_srl.experiments.train import max_episode_step

    path = folder / "episodes.jsonl"
    rows, note = read_episode_log(path, job.seeds, max_episode_step(job.train_config()))
    if note is not None and (folder / "metrics.json").exists():
        raise ValueError(f"{path} ends in a cut-off line although its job finished (metrics.json): the log is "
                         "damaged; restore it or delete the job's folder to run it again")
    return rows


class Results:
    """Every job of a study folder, looked up by (method, scene, options)."""

    def __init__(self, root: Path, state: dict, results: list[Result], profile: str | None = None):
        """profile None: the reproduction's jobs (the paper profile's, or every job of a study written before
        profiles); a name: that profile's set beyond the paper."""
        self.root, self.state, self.every, self.profile = root, state, results, profile
        mine = [r for r in results if (r.job.profile == profile and r.job.beyond_the_paper if profile
                                       else not r.job.beyond_the_paper)]
        self.by_key = {(r.job.method, r.job.scene, r.job.options): r for r in mine}
        self.budget = state.get("budget")
        self.levels = tuple(state.get("budget_config", {}).get("group1_levels") or TRAFFIC_LEVELS)

    def beyond(self) -> list["Results"]:
        """The other profiles' sets of the study, in the order they were run."""
        names = dict.fromkeys(r.job.profile for r in self.every if r.job.beyond_the_paper)
        return [Results(self.root, self.state, self.every, p) for p in names]

    def get(self, method: str, scene: str, options: tuple[str, ...] = ()) -> Result | None:
        return self.by_key.get((method, scene, tuple(options)))

    def __iter__(self):
        return iter(self.by_key.values())


def job_fraction(root: Path, job: Job) -> float:
    """How far a job's training is, 0..1, read from the last row of its scalars.csv (written every few
    thousand env steps by the worker); 0 when nothing is logged yet. Cheap: reads the file's tail only."""
    path = root / job.folder / "scalars.csv"
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 4096))
            last = f.read().decode("utf-8", "replace").strip().splitlines()[-1]
        step = float(last.split(",")[0])
    except (OSError, IndexError, ValueError):
        return 0.0
    return min(1.0, max(0.0, step / max(1, job.steps)))


STUDY_FIELDS = {"budget": "text", "created": "text?", "version": "text?", "commit": "text?"}
BUDGET_FIELDS = {"steps": "count", "envs": "count", "learning_starts": "count", "batch_size": "count",
                 "eval_episodes": "count", "replay_ratio": "number?"}
STUDY_OBJECTS = {"budget_config": dict, "jobs": dict, "invocations": list, "machine": dict}


def read_study(path: Path) -> dict:
    """A study.json, every field the tables and the report read checked: ValueError in one line naming the
    file and the field (a `{}` or a field of the wrong type would otherwise make a report of None values)."""
    state = check_fields(read_json(path), STUDY_FIELDS, str(path), ("created", "version", "commit"))
    for name, kind in STUDY_OBJECTS.items():
        if not isinstance(state.get(name, {} if name == "machine" else None), kind):
            raise ValueError(f"{path}: {name} must be a JSON {'object' if kind is dict else 'list'}, "
                             f"got {json.dumps(state.get(name))[:40]}")
    check_fields(state["budget_config"], BUDGET_FIELDS, f"{path}: budget_config", ("replay_ratio",))
    check_lists(state["budget_config"], {"seeds": "count", "group1_levels": "text"}, f"{path}: budget_config")
    for n, invocation in enumerate(state["invocations"]):
        check_fields(invocation, {}, f"{path}: invocations[{n}]")
    for job_id, entry in state["jobs"].items():
        where = f"{path}: jobs.{job_id}"
        check_fields(entry, {"status": "text", "message": "text?"}, where, ("status", "message"))
        job = check_fields(entry.get("job"), JOB_FIELDS, f"{where}.job", tuple(JOB_FIELDS)[2:])
        check_lists(job, JOB_LISTS, f"{where}.job")
        for name, known in (("method", METHOD_LABELS), ("scene", SCENES)):
            if job[name] not in known:
                raise ValueError(f"{where}.job: unknown {name} {job[name]!r}; this version knows {', '.join(known)}")
        try:
            Job.from_dict(job)
        except TypeError as err:
            raise ValueError(f"{where}.job is not a job of this version ({err})") from None
    return state


# a job as study.json records it (Job.to_dict); all but method and scene may be missing in older studies
JOB_FIELDS = {"method": "text", "scene": "text", "steps": "count", "envs": "count", "learning_starts": "count",
              "batch_size": "count", "replay_ratio": "number?", "checkpoint_every": "count",
              "eval_episodes": "count", "profile": "text", "adversary": "text"}
JOB_LISTS = {"options": "text", "seeds": "count", "eval_levels": "text", "artefacts": "text"}


def load_results(root: str | Path) -> Results:
    root = Path(root)
    state = read_study(root / "study.json")
    results = []
    for entry in state["jobs"].values():
        job = Job.from_dict(entry["job"])
        folder = root / job.folder
        res = Result(job, entry.get("status", "pending"), entry.get("message"), folder)
        if (folder / "metrics.json").exists():
            res.metrics = read_metrics(folder / "metrics.json")
        if (folder / "eval.json").exists():
            res.evaluation = read_eval(folder / "eval.json")
        if res.metrics is not None and res.evaluation is not None:
            res.status = "done"
        results.append(res)
    return Results(root, state, results)


def sd(values) -> float | None:
    vals = [float(v) for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    return statistics.stdev(vals) if len(vals) >= 2 else None
