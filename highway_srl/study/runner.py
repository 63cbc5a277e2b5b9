"""Run the study's jobs with an executor, local worker processes or a Ray cluster (study/executors.py); resume
where an earlier run stopped.

Layout of a study folder (`--out`):
  study.json                 budget, machine, provenance, every job's status, one entry per invocation
  runs/SCENE/VARIANT/        a training run folder (highway_srl.experiments.train) + eval.json + job.json
  tables/, figures/          the artefacts (highway_srl.study.tables / figures)
  report.md, report.html
  .lock                      held (flock) by the running reproduce: a second one on the folder is refused

A job is done when its folder holds metrics.json and eval.json; done jobs are never run again. A job whose
training was interrupted resumes from its last checkpoint (train_run(resume=True)); one that was trained
but not evaluated is only evaluated. Jobs whose method is not registered yet are recorded as
'unavailable' with the reason, failures as 'failed' with the error; both are tried again next time.
"""

from __future__ import annotations

import os
import platform
import socket
import time
from pathlib import Path
from typing import Callable

from highway_srl.experiments.runs import lock_run, open_state, provenance, read_json, write_json
from highway_srl.study.executors import EVAL_FILE, EXECUTORS, JOB_FILE, Work, now, run_job, run_local, run_ray
from highway_srl.study.jobs import Budget, Job, get_budget, job_availability, study_jobs
from highway_srl.study.results import job_fraction

STUDY_FILE = "study.json"


def job_done(root: Path, job: Job) -> bool:
    folder = root / job.folder
    return (folder / "metrics.json").exists() and (folder / EVAL_FILE).exists()


class StudyProgress:
    """A live bar over the pending jobs (unit: jobs, fractional while they train) with an ETA, redrawn
    every second by a daemon thread that reads each running job's scalars.csv; never touches the workers."""

    def __init__(self, root: Path, jobs: list[Job], enabled: bool = True, interval_s: float = 1.0):
        import threading

        from highway_srl.experiments.runs import progress_bar

        self.root, self.jobs, self.interval_s = root, list(jobs), interval_s
        self.finished: set[str] = set()
        self.shown = 0.0
        self.bar = progress_bar(len(self.jobs), "study", unit="job", enabled=enabled and bool(self.jobs))
        if self.bar is not None:  # resumed jobs' earlier steps: shown as done, but not as this run's rate
            self.shown = sum(job_fraction(root, j) for j in self.jobs)
            self.bar.initial = self.bar.n = round(self.shown, 2)
        self.stop = threading.Event()
        self.lock = threading.Lock()
        self.thread = threading.Thread(target=self._run, daemon=True) if self.bar is not None else None
        if self.thread is not None:
            self.thread.start()

    def job_finished(self, job: Job) -> None:
        with self.lock:
            self.finished.add(job.id)
        self.refresh()

    def refresh(self) -> None:
        if self.bar is None:
            return
        with self.lock:
            done = sum(1.0 if j.id in self.finished else job_fraction(self.root, j) for j in self.jobs)
            if done > self.shown:  # never backwards (a resumed job's log may restart below its old row)
                self.shown = done
                # set, not update: a sum of float increments would print as 0.39999999999999997/86
                self.bar.n = round(done, 2)
            self.bar.refresh()

    def _run(self) -> None:
        while not self.stop.wait(self.interval_s):
            self.refresh()

    def close(self) -> None:
        self.stop.set()
        if self.thread is not None:
            self.thread.join(timeout=5)
        if self.bar is not None:
            self.bar.close()


# ----------------------------------------------------------------------------------------------- the study
def machine(device: str = "cpu") -> dict:
    import torch

    info = {"host": socket.gethostname(), "platform": platform.platform(), "cpu": _cpu_model(),
            "cores": os.cpu_count(), "python": platform.python_version(), "torch": torch.__version__,
            "device": device, "cpu_kernels": torch.backends.cpu.get_cpu_capability(),  # AVX2 / AVX512: the last bits
            "mkl_cbwr": os.environ.get("MKL_CBWR", "")}  # MKL's reproducible mode, "" when not set (README)
    if device.startswith("cuda") and torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(0)
    return info


def cpuinfo(field: str) -> str | None:
    """A field of /proc/cpuinfo's first processor ("model name", "vendor_id", ...), None where there is none."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(field):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None


def _cpu_model() -> str:
    return cpuinfo("model name") or platform.processor() or platform.machine()


def open_study(out: Path, budget: Budget) -> dict:
    """The study.json of `out`, created if new; one-line errors for a folder that holds something else."""
    state = open_state(out, STUDY_FILE, "study")
    if state is not None:
        if state.get("budget") != budget.name:
            raise ValueError(f"--out {str(out)!r} holds a study of budget {state.get('budget')!r}, not "
                             f"{budget.name!r}; choose another --out or --budget {state.get('budget')}")
        changed = sorted(k for k, v in _settings(budget).items()
                         if _settings_of(state.get("budget_config", {})).get(k) != v)
        if changed:
            raise ValueError(f"--out {str(out)!r} holds a {budget.name} study made with other settings "
                             f"({', '.join(changed)} changed since); choose another --out")
        return state
    return {"kind": "highway-srl study", "budget": budget.name, "budget_config": vars(budget).copy(),
            "created": now(), "invocations": [], "jobs": {}, **provenance()}


def _settings(budget: Budget) -> dict:
    """The budget's numbers that shape the results (not its description), JSON-comparable."""
    return _settings_of(vars(budget))


def _settings_of(config: dict) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in config.items()
            if k not in ("name", "expected_cost")}


def reproduce(budget: str, out: str | Path, jobs: int | None = None, executor: str = "local",
              address: str | None = None, device: str = "cpu", methods: tuple[str, ...] | None = None,
              scenes: tuple[str, ...] | None = None, seeds: tuple[int, ...] | None = None,
              profiles: tuple[str, ...] | None = None, work: Work = run_job, log: Callable[[str], None] = print, report: bool = True,
              progress: bool = False) -> dict:
    """Run every pending job of the study at `budget` in `out`, then write the tables, figures and report.

    scenes / seeds: a part of the study (say, two-lane only) or other seeds than the budget's; the seeds
    become part of the budget's settings, so a folder is never resumed with different ones.
    Returns the final study.json content. `work` runs one job (run_job; tests pass stand-ins).
    progress: a live bar over the pending jobs with an ETA (the CLI's; job lines are then written above it).
    """
    from highway_srl.study.jobs import default_jobs

    b = _budget_with(get_budget(budget), seeds, profiles)
    workers = jobs if jobs is not None else default_jobs()
    _check_run_options(executor, address, device, workers)
    all_jobs = study_jobs(b, methods, scenes)
    out = Path(out)
    open_study(out, b)  # refuses a folder of another kind before a lock file is left in it
    out.mkdir(parents=True, exist_ok=True)
    with lock_run(out, f"--out {str(out)!r} is in use by another reproduce (pid {{pid}})"):
        state = open_study(out, b)  # again under the lock: the holder before may have changed it
        state["methods"] = list(methods) if methods else None
        state["scenes"] = list(scenes) if scenes else None
        state["machine"] = machine(device)
        state.update(provenance())
        invocation = {"started": now(), "executor": executor, "jobs": workers, "device": device, "address": address,
                      "host": state["machine"]["host"], **provenance(), "ran": 0, "skipped_done": 0, "finished": None,
                      "wall_s": None}
        state["invocations"].append(invocation)
        t0 = time.perf_counter()

        pending = _pending_jobs(all_jobs, out, state, invocation)
        write_json(out / STUDY_FILE, state)
        unavailable = [j for j in all_jobs if state["jobs"][j.id]["status"] == "unavailable"]
        log(f"study {b.name} in {out}: {len(all_jobs)} jobs, {invocation['skipped_done']} done already, "
            f"{len(pending)} to run, {len(unavailable)} unavailable (method not registered yet)"
            + (f"; {executor} executor, {workers} at a time (progress: {out}/runs/SCENE/VARIANT/scalars.csv)"
               if pending else ""))
        _run_pending(pending, out, state, invocation, t0, executor, address, device, workers, work, log, progress)
        log(_job_counts(all_jobs, state))
        if report:
            from highway_srl.study.report import write_report

            t1 = time.perf_counter()
            path = write_report(out)
            invocation["report_s"] = round(time.perf_counter() - t1, 2)
            invocation["wall_s"] = round(time.perf_counter() - t0, 2)
            write_json(out / STUDY_FILE, state)
            log(f"report: {path}")
        return state


def _job_counts(all_jobs: list[Job], state: dict) -> str:
    """The line that counts the study's jobs by status."""
    counts: dict[str, int] = {}
    for job in all_jobs:
        counts[state["jobs"][job.id]["status"]] = counts.get(state["jobs"][job.id]["status"], 0) + 1
    return (f"jobs: {', '.join(f'{n} {s}' for s, n in sorted(counts.items()))}"
            + ("; run the same command again to retry the others" if set(counts) - {"done"} else ""))


def report_only(out: str | Path, budget: str | None = None) -> Path:
    """The tables, figures and report of the study in `out` from the jobs finished so far; runs nothing.

    Why: a paper-budget study takes days; this shows where it stands (unfinished jobs are '–' cells and the
    report counts them) while it runs in another process or after a stop. study.json is only read, never
    written, so a running study's record is not disturbed; its own report, at its end, replaces this one.
    budget: if given, it must be the study's (the same command line as the study's, plus --report-only).
    A folder without study.json whose subfolders are studies of one budget differing only in seeds (seed
    chunks, chunks.py) gets one report over the union of their finished jobs.
    """
    from highway_srl.study.report import write_report

    from highway_srl.study.chunks import check_chunks, chunk_folders
    from highway_srl.study.results import load_results

    out = Path(out)
    parts = chunk_folders(out) if not (out / STUDY_FILE).exists() else []
    if parts:  # a study run in seed chunks: one report over them all
        check_chunks([load_results(p) for p in parts], budget)
        return write_report(out)
    state = open_state(out, STUDY_FILE, "study")
    if state is None:
        raise ValueError(f"--out {str(out)!r} holds no study (study.json) and no seed chunks (subfolders with "
                         "one): start one with reproduce --budget ...")
    if budget is not None and state.get("budget") != budget:
        raise ValueError(f"--out {str(out)!r} holds a study of budget {state.get('budget')!r}, not {budget!r}")
    return write_report(out)


def _budget_with(b: Budget, seeds: tuple[int, ...] | None, profiles: tuple[str, ...] | None) -> Budget:
    """The budget with reproduce's --seeds / --profiles, checked (ValueError names the bad value)."""
    from dataclasses import replace

    if seeds is not None:
        if not seeds or len(set(seeds)) != len(seeds) or any(s < 0 for s in seeds):
            raise ValueError(f"--seeds must be distinct non-negative integers, got {','.join(map(str, seeds))}")
        b = replace(b, seeds=tuple(seeds))
    if profiles is not None:  # like the seeds, part of the budget's settings: a folder never mixes sets
        from highway_srl.rules import PROFILES

        unknown = [p for p in profiles if p not in PROFILES]
        # paper, if named, first: the reproduction; a chunk of one other profile alone runs only its jobs
        if not profiles or unknown or len(set(profiles)) != len(profiles) or "paper" in profiles[1:]:
            raise ValueError(f"--profiles takes distinct names of {', '.join(PROFILES)}, paper (if named) first "
                             f"(the reproduction), got {','.join(profiles)}")
        b = replace(b, profiles=tuple(profiles))
    return b


def _check_run_options(executor: str, address: str | None, device: str, workers: int) -> None:
    """ValueError for an unknown executor or device, --address without Ray, --jobs < 1, or Ray missing."""
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor {executor!r}; choose one of {', '.join(EXECUTORS)}")
    if address and executor != "ray":
        raise ValueError("--address is for --executor ray")
    if device not in ("cpu", "cuda") and not device.startswith("cuda:"):
        raise ValueError(f"unknown device {device!r}; choose cpu or cuda")
    if workers < 1:
        raise ValueError(f"--jobs must be a positive integer, got {workers}")
    if executor == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ValueError("the ray executor needs Ray: pip install 'highway-srl[ray]'") from None


def _pending_jobs(all_jobs: list[Job], out: Path, state: dict, invocation: dict) -> list[Job]:
    """The jobs to run; marks each job's entry in state done (its files are there), unavailable (its method
    is not registered) or pending, and counts the done ones in the invocation."""
    pending = []
    for job in all_jobs:
        entry = state["jobs"].setdefault(job.id, {})
        entry["job"] = job.to_dict()
        if job_done(out, job):
            if entry.get("status") != "done":
                entry.update(_from_job_file(out, job))
                entry["status"] = "done"
            invocation["skipped_done"] += 1
            continue
        why = job_availability(job)
        if why is not None:
            entry.update(status="unavailable", message=why, wall_s=None, finished=now())
            continue
        entry.update(status="pending", message=None)
        pending.append(job)
    return pending


def _run_pending(pending: list[Job], out: Path, state: dict, invocation: dict, t0: float, executor: str,
                 address: str | None, device: str, workers: int, work: Work, log: Callable[[str], None],
                 progress: bool) -> None:
    """Run the pending jobs on the executor; study.json is rewritten after each result and at the end."""
    counter = {"n": 0}
    bar = StudyProgress(out, pending, enabled=progress)
    if bar.bar is not None:
        log = bar.bar.write  # job lines go above the live bar, not through it

    def on_result(job: Job, result: dict) -> None:
        bar.job_finished(job)
        counter["n"] += 1
        entry = state["jobs"][job.id]
        entry.update(status=result.get("status", "failed"), message=result.get("message"),
                     wall_s=result.get("wall_s"), finished=result.get("finished", now()), host=result.get("host"))
        invocation["ran"] += 1
        invocation["wall_s"] = round(time.perf_counter() - t0, 2)
        write_json(out / STUDY_FILE, state)
        what = f"done in {result['wall_s']:.0f} s" if entry["status"] == "done" else f"FAILED: {entry['message']}"
        log(f"[{counter['n']}/{len(pending)}] {job.id}: {what}")

    try:
        if pending:
            if executor == "local":
                run_local(pending, out, device, workers, on_result, work)
            else:
                run_ray(pending, out, device, on_result, address=address, num_cpus=workers, work=work)
    finally:
        bar.close()
        invocation["finished"] = now()
        invocation["wall_s"] = round(time.perf_counter() - t0, 2)
        write_json(out / STUDY_FILE, state)


def _from_job_file(out: Path, job: Job) -> dict:
    path = out / job.folder / JOB_FILE
    if path.exists():
        try:
            saved = read_json(path)
            return {k: saved.get(k) for k in ("message", "wall_s", "finished", "host")}
        except ValueError:
            pass
    return {"message": None, "wall_s": None, "finished": None, "host": None}
