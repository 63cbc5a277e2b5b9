"""`highway-srl transfer`: train in our simulator, deploy the same policy in SUMO and highway-env.

Each job trains one method on one scenario at level C in our simulator (one seed), then evaluates the greedy
policy on the same episode seeds in every simulator asked for. The policy never sees another simulator in
training, so the table says how much of what it learned survives other physics and other traffic models.

Layout of `--out`:
  transfer.json              the settings, machine, provenance and every job's status and timings
  runs/SCENE/METHOD/         a training run folder + eval-SIM.json for each simulator + transfer-job.json
  transfer.csv, transfer.md  the side-by-side table

Finished evaluations are never run again: run the same command to resume an interrupted study.
"""

from __future__ import annotations

import json
import time
import traceback
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import Callable

from highway_srl.constants import TRAFFIC_LEVELS
from highway_srl.experiments.records import check_fields, read_eval, read_metrics
from highway_srl.experiments.runs import open_state, provenance, read_json, write_json
from highway_srl.study.jobs import METHOD_LABELS, SCENES, Job
from highway_srl.study.table import Column, Table

SIMULATORS = ("ours", "sumo", "highway-env")
SIMULATOR_LABELS = {"ours": "ours", "sumo": "SUMO", "highway-env": "highway-env"}
TRANSFER_SCENES = ("two-lane", "multi-lane", "merge", "exit")
TRANSFER_METHODS = ("moe-rm-srl", "mp-rl", "rl")  # ours, a shield with the same mappings, no shield at all
STATE_FILE = "transfer.json"
JOB_FILE = "transfer-job.json"


@dataclass(frozen=True)
class TransferSettings:
    steps: int = 100_000  # environment steps of training per run
    envs: int = 16
    seed: int = 0
    episodes: int = 50  # deployment episodes per simulator
    traffic: str = "C"  # training and deployment level
    learning_starts: int = 1_000
    batch_size: int = 256
    replay_ratio: float = 0.25  # gradient steps per env step (Algorithm 1: 1; 0.25 = the former 4 per 16 envs)

    def check(self) -> None:
        for name in ("steps", "envs", "episodes", "batch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be positive, got {getattr(self, name)}")
        if not self.replay_ratio >= 0:
            raise ValueError(f"replay_ratio must be non-negative, got {self.replay_ratio}")
        if self.seed < 0:
            raise ValueError(f"--seed must be non-negative, got {self.seed}")
        if self.traffic not in TRAFFIC_LEVELS:
            raise ValueError(f"unknown traffic level {self.traffic!r}; choose one of {', '.join(TRAFFIC_LEVELS)}")


def eval_file(simulator: str) -> str:
    return "eval.json" if simulator == "ours" else f"eval-{simulator}.json"


def transfer_jobs(settings: TransferSettings, methods=TRANSFER_METHODS, scenes=TRANSFER_SCENES) -> list[Job]:
    for m in methods:
        if m not in METHOD_LABELS:
            raise ValueError(f"unknown method {m!r}; choose from {', '.join(METHOD_LABELS)}")
    for s in scenes:
        if s not in TRANSFER_SCENES:
            raise ValueError(f"unknown scene {s!r}; the transfer study runs {', '.join(TRANSFER_SCENES)}")
    if settings.traffic != "C":  # Job.train_config trains at the study's level C
        raise ValueError("the transfer study trains at level C (the paper's training level)")
    return [Job(method=m, scene=s, seeds=(settings.seed,), steps=settings.steps, envs=settings.envs,
                learning_starts=settings.learning_starts, batch_size=settings.batch_size,
                replay_ratio=settings.replay_ratio, checkpoint_every=max(settings.steps // 5, 1),
                eval_levels=(settings.traffic,), eval_episodes=settings.episodes)
            for s in scenes for m in methods]


def job_done(root: Path, job: Job, simulators) -> bool:
    """Whether the job's run and every evaluation asked for are there; the files that are there are read
    (records.read_metrics, read_eval, earlier_timings), so that a damaged one stops the study before
    anything is written."""
    folder = root / job.folder
    if (folder / "metrics.json").exists():
        read_metrics(folder / "metrics.json")
    earlier_timings(folder / JOB_FILE)
    evals = [folder / eval_file(s) for s in simulators]
    for path in evals:
        if path.exists():
            read_eval(path)
    return (folder / "metrics.json").exists() and all(path.exists() for path in evals)


def earlier_timings(path: Path) -> dict:
    """The evaluations' seconds by simulator of a job's transfer-job.json ({} before its first result),
    checked: ValueError in one line naming the file and the field."""
    if not path.exists():
        return {}
    record = check_fields(read_json(path), {}, str(path))
    timings = record.get("eval_s", {})
    check_fields(timings, dict.fromkeys(timings, "number"), f"{path}: eval_s")
    return timings


def run_transfer_job(job_dict: dict, root: str, device: str = "cpu", threads: int = 1,
                     simulators: tuple[str, ...] = SIMULATORS) -> dict:
    """Train (or resume) one job in our simulator, then evaluate it in each simulator; never raises."""
    import torch

    from highway_srl.experiments.evaluate import evaluate_run
    from highway_srl.experiments.train import train_run

    torch.set_num_threads(max(1, threads))
    job = Job.from_dict(job_dict)
    folder = Path(root) / job.folder
    result = {"status": "done", "message": None, "eval_s": {}}
    started = time.perf_counter()
    try:
        if not (folder / "metrics.json").exists():
            train_run(job.train_config(device), folder, resume=(folder / "config.json").exists(),
                      checkpoint_every=job.checkpoint_every, progress=False)
        for sim in simulators:
            path = folder / eval_file(sim)
            if path.exists():
                continue
            t0 = time.perf_counter()
            evaluate_run(folder, traffics=list(job.eval_levels), episodes=job.eval_episodes, device=device,
                         backend=sim, out=path)
            result["eval_s"][sim] = round(time.perf_counter() - t0, 2)
    except Exception as err:  # noqa: BLE001 - a failing job is recorded, the others go on
        result.update(status="failed", message=f"{type(err).__name__}: {err}",
                      traceback=traceback.format_exc(limit=8))
    result["wall_s"] = round(time.perf_counter() - started, 2)
    result["eval_s"] = {**earlier_timings(folder / JOB_FILE), **result["eval_s"]}
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / JOB_FILE, {"job": job.to_dict(), **result, **provenance()})
    return result


def run_transfer(out: str | Path, settings: TransferSettings = TransferSettings(), methods=TRANSFER_METHODS,
                 scenes=TRANSFER_SCENES, simulators=SIMULATORS, jobs: int = 1, device: str = "cpu",
                 log: Callable[[str], None] = print) -> Path:
    """Run every pending job, then write the table; returns the Markdown table's path."""
    from highway_srl.backends import missing_modules
    from highway_srl.experiments.bench import check_sim_memory
    from highway_srl.study.executors import now, run_local
    from highway_srl.study.runner import machine

    settings.check()
    for sim in simulators:
        if sim not in SIMULATORS:
            raise ValueError(f"unknown simulator {sim!r}; choose from {', '.join(SIMULATORS)}")
    if jobs < 1:
        raise ValueError(f"--jobs must be positive, got {jobs}")
    all_jobs = transfer_jobs(settings, methods, scenes)  # unknown methods and scenes are named first
    for scene in dict.fromkeys(j.scene for j in all_jobs):  # as evaluate: every episode is an env of one world
        check_sim_memory(SCENES[scene].scenario, settings.traffic, settings.episodes, device,
                         SCENES[scene].adversarial, "use fewer --episodes")
    for sim in simulators:  # then what is not installed: a typo is not answered with "pip install"
        missing = missing_modules(sim)
        if missing:
            raise ValueError(f"simulator {sim!r} needs modules {', '.join(missing)}: "
                             f"pip install 'highway-srl[{sim}]' (or leave it out of --simulators)")
    root = Path(out)
    state = _open(root, settings)
    root.mkdir(parents=True, exist_ok=True)
    state.update(machine=machine(device), **provenance())
    pending = [j for j in all_jobs if not job_done(root, j, simulators)]
    for j in all_jobs:
        state["jobs"].setdefault(j.id, {"status": "pending"})
        if j not in pending:
            state["jobs"][j.id]["status"] = "done"
    write_json(root / STATE_FILE, state)
    log(f"transfer study in {root}: {len(all_jobs)} jobs, {len(all_jobs) - len(pending)} done already, "
        f"{len(pending)} to run, {jobs} at a time; simulators {', '.join(simulators)}")
    t0 = time.perf_counter()
    counter = {"n": 0}

    def on_result(job: Job, result: dict) -> None:
        counter["n"] += 1
        state["jobs"][job.id] = {k: result.get(k) for k in ("status", "message", "wall_s", "eval_s")}
        state["jobs"][job.id]["finished"] = now()
        write_json(root / STATE_FILE, state)
        what = f"done in {result['wall_s']:.0f} s" if result.get("status") == "done" else \
            f"FAILED: {result.get('message')}"
        log(f"[{counter['n']}/{len(pending)}] {job.id}: {what}")

    if pending:
        run_local(pending, root, device, jobs, on_result, partial(run_transfer_job, simulators=tuple(simulators)))
    state["wall_s"] = round(state.get("wall_s", 0.0) + time.perf_counter() - t0, 2)
    write_json(root / STATE_FILE, state)
    table = transfer_table(root, all_jobs, simulators, settings)
    table.write(root)
    log(f"table: {root / 'transfer.md'}")
    return root / "transfer.md"


STATE_KIND = "highway-srl transfer study"


def check_state(state, path: Path) -> dict:
    """A transfer.json, every field run_transfer reads or updates checked: ValueError in one line naming the
    file and the field (a `{}`, a list or a null would otherwise be taken for a new study, or fail midway)."""
    check_fields(state, {"kind": "text", "created": "text?", "wall_s": "number"}, str(path), ("created", "wall_s"))
    if state["kind"] != STATE_KIND:
        raise ValueError(f"{path} is no transfer study (its kind is {state['kind']!r})")
    for name in ("settings", "jobs"):
        if not isinstance(state.get(name), dict):
            raise ValueError(f"{path}: {name} must be a JSON object, got {json.dumps(state.get(name))[:40]}")
    for job_id, entry in state["jobs"].items():
        check_fields(entry, {"status": "text", "message": "text?"}, f"{path}: jobs.{job_id}", ("message",))
    return state


def _open(root: Path, settings: TransferSettings) -> dict:
    state = open_state(root, STATE_FILE, "transfer study")
    if state is not None:
        check_state(state, root / STATE_FILE)
        if state.get("settings") != asdict(settings):
            changed = sorted(k for k, v in asdict(settings).items() if state.get("settings", {}).get(k) != v)
            raise ValueError(f"--out {str(root)!r} holds a transfer study made with other settings "
                             f"({', '.join(changed)}); choose another --out")
        return state
    return {"kind": STATE_KIND, "settings": asdict(settings), "created": time.strftime(
        "%Y-%m-%dT%H:%M:%S%z"), "jobs": {}}


def transfer_rows(root: Path, jobs: list[Job], simulators, traffic: str) -> list[dict]:
    """One row per (scene, method, simulator) with C_r and its interval, average speed, R_r and R_s."""
    rows = []
    for job in jobs:
        for sim in simulators:
            path = Path(root) / job.folder / eval_file(sim)
            row = {"scene": job.scene, "method": job.method, "simulator": sim}
            if path.exists():
                level = read_eval(path)["levels"].get(traffic, {})
                row["episodes"] = level.get("episodes")
                for key, name in (("C_r", "C_r"), ("avg_speed", "speed"), ("R_r", "R_r"), ("R_s", "R_s")):
                    if key in level:
                        row[name] = level[key]["value"]
                        row[f"{name}_low"], row[f"{name}_high"] = level[key]["low"], level[key]["high"]
            rows.append(row)
    return rows


def transfer_table(root: Path, jobs: list[Job], simulators, settings: TransferSettings) -> Table:
    rows = transfer_rows(root, jobs, simulators, settings.traffic)
    columns = [Column("scene", "scene"), Column("method", "method"), Column("simulator", "simulator"),
               Column("episodes", "episodes", "int"),
               Column("C_r", "C_r"), Column("C_r_low", "C_r low"), Column("C_r_high", "C_r high"),
               Column("speed", "speed (m/s)"), Column("R_r", "R_r"), Column("R_s", "R_s")]
    table = Table("transfer", f"Transfer: trained in ours, deployed in {', '.join(simulators)}", columns, rows)
    wide, cells = [], {}
    for row in rows:
        key = (row["scene"], row["method"])
        if key not in cells:
            cells[key] = {"scene": SCENES[row["scene"]].label, "method": METHOD_LABELS.get(row["method"])}
            wide.append(cells[key])
        sim = row["simulator"]
        cells[key][f"{sim}_C_r"] = _pct(row.get("C_r"))
        cells[key][f"{sim}_speed"] = "–" if row.get("speed") is None else f"{row['speed']:.2f}"
        cells[key][f"{sim}_R_s"] = _pct(row.get("R_s"))
    wide_cols = [Column("scene", "scene"), Column("method", "method")]
    for metric, header in (("C_r", "collision-free C_r"), ("speed", "speed (m/s)"), ("R_s", "success R_s")):
        wide_cols += [Column(f"{s}_{metric}", f"{header}: {SIMULATOR_LABELS[s]}") for s in simulators]
    table.display = Table("transfer", table.title, wide_cols, wide)
    table.notes = [f"Trained {settings.steps:,} env steps at level {settings.traffic} in our simulator (seed "
                   f"{settings.seed}, {settings.envs} envs, batch {settings.batch_size}, replay ratio "
                   f"{settings.replay_ratio:g} update(s) per env step); {settings.episodes} greedy episodes per simulator on the same episode "
                   "seeds. R_s only on merge and exit. CSV: 95 % intervals of C_r."]
    return table


def _pct(v) -> str:
    return "–" if v is None else f"{100 * v:.0f}%"
