"""One study job, trained and evaluated (run_job), and what runs the jobs: local worker processes (run_local)
or a Ray cluster (run_ray)."""

from __future__ import annotations

import os
import socket
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

from highway_srl.experiments.runs import default_threads, provenance, write_json
from highway_srl.interrupts import exit_at_once, held, quiet_worker
from highway_srl.study.jobs import Job

EXECUTORS = ("local", "ray")  # what runs the jobs (the simulators are highway_srl.backends)
EVAL_FILE = "eval.json"
JOB_FILE = "job.json"
RESULT_FILES = ("config.json", "metrics.json", EVAL_FILE, "episodes.jsonl", JOB_FILE)  # what tables read
RAY_JOBS_PER_GPU = 4  # with --device cuda on Ray, each job asks for 1/4 of a GPU


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


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
        except BaseException:  # Ctrl-C or `kill` (which may have reached this process alone)
            pool.shutdown(wait=False, cancel_futures=True)
            # end the workers at once: one still starting holds SIGINT and SIGTERM until exit_with_parent,
            # seconds of imports away, and the pool's exit would wait for it; a running job ends as after
            # Ctrl-C (exit_at_once: no clean-up either) and resumes from its last checkpoint
            for child in mp.active_children():
                child.kill()
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
