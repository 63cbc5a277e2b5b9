"""Run the study's jobs with an executor, local worker processes or a Ray cluster; resume where an earlier
run stopped.

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
import signal
import socket
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

from highway_srl.experiments.runs import default_threads, lock_run, open_state, provenance, read_json, write_json
from highway_srl.interrupts import exit_at_once, held, quiet_worker
from highway_srl.study.jobs import Budget, Job, get_budget, job_availability, study_jobs
from highway_srl.study.tables import job_fraction

EXECUTORS = ("local", "ray")  # what runs the jobs (the simulators are highway_srl.backends)
STUDY_FILE = "study.json"
EVAL_FILE = "eval.json"
JOB_FILE = "job.json"
RESULT_FILES = ("config.json", "metrics.json", EVAL_FILE, "episodes.jsonl", JOB_FILE)  # what tables read
RAY_JOBS_PER_GPU = 4  # with --device cuda on Ray, each job asks for 1/4 of a GPU


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


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


# ----------------------------------------------------------------------------------------------- one job
def run_job(job_dict: dict, root: str, device: str = "cpu", threads: int = 1, return_files: bool = False) -> dict:
    """Train (or resume) and evaluate one job; never raises. Runs in a worker process or a Ray task.

    Returns {"status": "done" | "failed", "message", "wall_s", "host", "trained", "evaluated"} and, with
    return_files, the text of the result files so a driver without the worker's file system can keep them.
    """
    import torch

    torch.set_num_threads(max(1, threads))
    job = Job.from_dict(job_dict)
    folder = Path(root) / job.folder
    started = time.perf_counter()
    result = {"status": "done", "message": None, "host": socket.gethostname(), "trained": False, "evaluated": False}
    try:
        from highway_srl.experiments.evaluate import evaluate_run
        from highway_srl.experiments.train import train_run

        if not (folder / "metrics.json").exists():
            resume = (folder / "config.json").exists()
            train_run(job.train_config(device), folder, resume=resume, checkpoint_every=job.checkpoint_every,
                      progress=False)
            result["trained"] = True
        if not (folder / EVAL_FILE).exists():
            evaluate_run(folder, traffics=list(job.eval_levels), episodes=job.eval_episodes, device=device,
                         out=folder / EVAL_FILE)
            result["evaluated"] = True
    except Exception as err:  # noqa: BLE001 - a failing job is recorded, the study goes on
        result.update(status="failed", message=f"{type(err).__name__}: {err}",
                      traceback=traceback.format_exc(limit=8))
    result["wall_s"] = round(time.perf_counter() - started, 2)
    result["finished"] = now()
    try:
        write_json(folder / JOB_FILE, {"job": job.to_dict(), **result, **provenance()})
    except OSError as err:
        result.update(status="failed", message=f"cannot write {folder / JOB_FILE}: {err}")
    if return_files:
        result["files"] = {name: (folder / name).read_text() for name in RESULT_FILES if (folder / name).exists()}
    return result


Work = Callable[..., dict]  # run_job's signature; tests pass cheaper stand-ins


# ---------------------------------------------------------------------------------------------- executors
def gpu_count() -> int:
    import torch

    return torch.cuda.device_count() if torch.cuda.is_available() else 0


def place_jobs(device: str, count: int, gpus: int) -> list[str]:
    """The device of each of `count` jobs in the order they are handed out. --device cuda with several GPUs:
    round robin over them (cuda:0, cuda:1, ...), so that the workers spread over every GPU; otherwise (one
    GPU, an explicit cuda:N, the CPU) the device as given. Either way the `--jobs N` worker processes train
    their jobs at once, N on one GPU sharing it (each its own process and CUDA context)."""
    if device != "cuda" or gpus <= 1:
        return [device] * count
    return [f"cuda:{i % gpus}" for i in range(count)]


def exit_with_parent(parent_pid: int, poll_s: float = 1.0) -> None:
    """Worker initializer: end this worker once the study process that started it is gone (killed with
    `kill -9 PID`; after Ctrl-C or `kill PID` it ends its workers itself). An orphaned worker would go on training and
    hold its run folder's lock, so the next `reproduce` would record that job as failed. A job killed
    this way resumes from its last checkpoint (files are written atomically)."""
    import threading

    quiet_worker(exit_at_once)  # Ctrl-C: the study process reports it; the job resumes as after `kill`

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def run_local(jobs: list[Job], root: Path, device: str, workers: int, on_result, work: Work = run_job) -> None:
    """`workers` worker processes (spawned, reused across jobs); one job runs inline when workers == 1.
    Jobs go to devices by place_jobs."""
    threads = default_threads()  # per worker: one unless OMP_NUM_THREADS (or the CLI's --threads) says more
    devices = place_jobs(device, len(jobs), gpu_count() if device == "cuda" else 0)
    if workers <= 1 or len(jobs) <= 1:
        for job, dev in zip(jobs, devices):
            on_result(job, work(job.to_dict(), str(root), dev, threads))
        return
    import multiprocessing as mp

    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=mp.get_context("spawn"),
                             initializer=exit_with_parent, initargs=(os.getpid(),)) as pool:
        try:
            with held():  # the workers start deaf to Ctrl-C until exit_with_parent (interrupts.py)
                futures = {pool.submit(work, job.to_dict(), str(root), dev, threads): job
                           for job, dev in zip(jobs, devices)}
            for fut in as_completed(futures):
                job = futures[fut]
                try:
                    result = fut.result()
                except BrokenProcessPool:
                    result = {"status": "failed", "message": "a worker process died (killed, or out of memory?)",
                              "wall_s": None}
                except Exception as err:  # noqa: BLE001 - e.g. the job could not be sent to the worker
                    result = {"status": "failed", "message": f"{type(err).__name__}: {err}", "wall_s": None}
                on_result(job, result)
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            for child in mp.active_children():  # `kill` reached this process alone: end the jobs as Ctrl-C does
                try:
                    os.kill(child.pid, signal.SIGINT)
                except ProcessLookupError:  # it ended meanwhile
                    pass
            raise


def run_ray(jobs: list[Job], root: Path, device: str, on_result, address: str | None = None,
            num_cpus: int | None = None, work: Work = run_job) -> None:
    """One Ray task per job (1 CPU; 1/4 GPU with --device cuda). Uses an already initialised Ray, else
    connects to `address`, else starts a local one with `num_cpus`. Workers write to the same path (a shared
    file system); the tables' files also travel back with each result, so a cluster without one works too
    (model weights and resume checkpoints then stay on the worker)."""
    try:
        import ray
    except ImportError:
        raise ValueError("the ray executor needs Ray: pip install 'highway-srl[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        kwargs = {"address": address} if address else {"num_cpus": num_cpus}
        ray.init(include_dashboard=False, ignore_reinit_error=True, log_to_driver=False, **kwargs)
    try:
        gpus = 1.0 / RAY_JOBS_PER_GPU if device.startswith("cuda") else 0
        task = ray.remote(work).options(num_cpus=1, num_gpus=gpus, max_retries=0)
        refs = {task.remote(job.to_dict(), str(root), device, 1, True): job for job in jobs}
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1)
            for ref in ready:
                job = refs.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as err:  # noqa: BLE001 - a dead worker or node
                    result = {"status": "failed", "message": f"ray task failed: {type(err).__name__}: {err}",
                              "wall_s": None}
                _keep_files(root / job.folder, result.pop("files", None) or {})
                on_result(job, result)
    finally:
        if started_here:
            ray.shutdown()


def _keep_files(folder: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = folder / name
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{name}.tmp")
            tmp.write_text(text)
            os.replace(tmp, path)


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
    from highway_srl.study.tables import load_results

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
        if not profiles or unknown or len(set(profiles)) != len(profiles) or profiles[0] != "paper":
            raise ValueError(f"--profiles takes distinct names of {', '.join(PROFILES)}, paper first (the "
                             f"reproduction), got {','.join(profiles)}")
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
