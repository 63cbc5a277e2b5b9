"""Synthetic job results for the study's tests, written by the project's own writers.

`write_fake_job` fills a run folder the way run_job would (config.json, episodes.jsonl, metrics.json from
`training_metrics`, eval.json from `evaluate.summarise`), with numbers chosen by the test, in a fraction of
a second. `fake_work` has run_job's signature, so `reproduce(..., work=fake_work)` runs the whole study
machinery on it; numbers come from ROOT.numbers.json beside the study folder (job id -> numbers) if present.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from highway_srl.constants import TRAFFIC_LEVELS
from highway_srl.experiments.collisions import CREEP, DECISION_CLASSES
from highway_srl.experiments.collisions import summarise as census_summary
from highway_srl.experiments.evaluate import summarise
from highway_srl.experiments.runs import append_jsonl, provenance, write_json
from highway_srl.study.jobs import OURS, SCENES, Job
from highway_srl.experiments.training_metrics import training_metrics

GOOD = {"T_c": 1.0, "rise": 0.3, "C_r": 1.0, "speed": 8.0, "R_r": 220.0, "R_s": 0.8}
POOR = {"T_c": 0.5, "rise": 0.8, "C_r": 0.7, "speed": 6.0, "R_r": 100.0, "R_s": 0.4}


def default_numbers(job: Job) -> dict:
    return dict(GOOD if (job.method == OURS and not job.options) else POOR)


def write_fake_job(root: Path, job: Job, numbers: dict | None = None, episodes_per_seed: int = 20) -> Path:
    """A finished run folder for `job` whose metrics come out as `numbers` (see GOOD for the keys)."""
    n = {**default_numbers(job), **(numbers or {})}
    folder = Path(root) / job.folder
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / "config.json", {"config": job.train_config().to_dict(), **provenance()})
    rows = []
    collided_count = round((1.0 - n["T_c"]) * episodes_per_seed)
    for seed in job.seeds:
        for i in range(episodes_per_seed):
            step = (i + 1) * job.steps // episodes_per_seed
            ret = 200.0 if step >= n["rise"] * job.steps else -100.0  # a step: the return rises at n["rise"]
            rows.append({"seed": seed, "step": step, "return": ret, "length": 320, "collision": i < collided_count,
                         "avg_speed": n["speed"], "success": False, "deploy_reward": ret})
    append_jsonl(folder / "episodes.jsonl", rows)
    metrics = training_metrics(rows, list(job.seeds))
    metrics.update({"method": job.method, "scenario": SCENES[job.scene].scenario, "traffic": "C",
                    "adversarial": SCENES[job.scene].adversarial, "env_steps_per_seed": job.steps,
                    "seeds": list(job.seeds), "wall_s": 1.0, "env_steps_per_s": 1000.0, "device": "cpu",
                    **provenance()})
    write_json(folder / "metrics.json", metrics)
    scenario = SCENES[job.scene].scenario
    report = {"run": str(folder), "method": job.method, "scenario": scenario,
              "adversarial": SCENES[job.scene].adversarial, "backend": "ours", "episodes_per_level": job.eval_episodes,
              "trained_seeds": list(job.seeds), "levels": {}, **provenance()}
    k = job.eval_episodes
    for level in job.eval_levels:
        slower = 0.5 * list(TRAFFIC_LEVELS).index(level)
        per = []
        for _ in job.seeds:
            bad = round((1.0 - n["C_r"]) * k)
            good = round(n["R_s"] * k)
            per.append({"collided": torch.arange(k) < bad, "success": torch.arange(k) >= k - good,
                        "avg_speed": torch.full((k,), n["speed"] - slower) + 0.01 * torch.arange(k),
                        "deploy_reward": torch.full((k,), float(n["R_r"])) + 0.1 * torch.arange(k)})
        results = {key: torch.cat([p[key] for p in per]) for key in per[0]}
        lv = summarise(results, scenario)
        crash = {"kind": "front", "ego_changing": False, "sv": "keeping lane", "ego_speed": 1.0, "sv_speed": 0.0}
        hits = int(results["collided"].sum())
        lv["collisions"] = {**census_summary([crash] * hits),  # as evaluate's census and decision trace
                            "by_decision": {**dict.fromkeys(DECISION_CLASSES, 0), CREEP: hits}}
        lv["per_seed"] = {str(s): summarise(p, scenario) for s, p in zip(job.seeds, per)} if len(per) > 1 else None
        report["levels"][level] = lv
    write_json(folder / "eval.json", report)
    return folder


def fake_work(job_dict: dict, root: str, device: str = "cpu", threads: int = 1, return_files: bool = False) -> dict:
    """Stands in for executors.run_job: writes a finished folder, counts its calls in ROOT.calls.jsonl."""
    job = Job.from_dict(job_dict)
    numbers_path = Path(f"{root}.numbers.json")
    numbers = json.loads(numbers_path.read_text()).get(job.id) if numbers_path.exists() else None
    write_fake_job(Path(root), job, numbers)
    with open(f"{root}.calls.jsonl", "a") as f:
        f.write(json.dumps({"job": job.id}) + "\n")
    return {"status": "done", "message": None, "wall_s": 0.01, "host": "test"}


def device_work(job_dict: dict, root: str, device: str = "cpu", threads: int = 1, return_files: bool = False) -> dict:
    """fake_work that also records the device and process each job was given, in ROOT.devices.jsonl."""
    import os

    with open(f"{root}.devices.jsonl", "a") as f:
        f.write(json.dumps({"job": Job.from_dict(job_dict).id, "device": device, "pid": os.getpid()}) + "\n")
    return fake_work(job_dict, root, device, threads, return_files)


def calls(root: Path) -> list[str]:
    path = Path(f"{root}.calls.jsonl")
    return [json.loads(line)["job"] for line in path.read_text().splitlines()] if path.exists() else []
