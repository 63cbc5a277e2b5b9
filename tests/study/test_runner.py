"""Running the study: resume skips finished jobs, failures and unregistered methods are recorded, parallel
workers, and one-line errors for bad input."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest
import study_fakes as fakes

from highway_srl.agents import registry as methods_mod
from highway_srl.cli import main
from highway_srl.experiments import evaluate as evaluate_mod
from highway_srl.experiments import train as train_mod
from highway_srl.study import executors
from highway_srl.study.executors import place_jobs, run_job
from highway_srl.study.runner import reproduce
from highway_srl.experiments.runs import read_json
from highway_srl.study.jobs import OURS, study_jobs

QUIET = {"log": lambda s: None, "report": False}


def test_resume_runs_only_the_jobs_that_are_not_finished(tmp_path):
    root = tmp_path / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, **QUIET)
    jobs = study_jobs("smoke")
    assert sorted(fakes.calls(root)) == sorted(j.id for j in jobs)
    stamps = {j.id: (root / j.folder / "metrics.json").stat().st_mtime_ns for j in jobs}

    state = reproduce("smoke", root, jobs=1, work=fakes.fake_work, **QUIET)
    assert len(fakes.calls(root)) == len(jobs)  # nothing ran again
    assert state["invocations"][-1]["ran"] == 0 and state["invocations"][-1]["skipped_done"] == len(jobs)
    assert {j.id: (root / j.folder / "metrics.json").stat().st_mtime_ns for j in jobs} == stamps

    (root / jobs[5].folder / "eval.json").unlink()  # trained, not evaluated: not done
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, **QUIET)
    assert fakes.calls(root)[len(jobs):] == [jobs[5].id]


def test_run_job_resumes_a_half_trained_run_and_only_evaluates_a_trained_one(tmp_path, monkeypatch):
    seen = []
    monkeypatch.setattr(train_mod, "train_run", lambda cfg, out, resume, **kw: seen.append(("train", resume)) or
                        (out / "metrics.json").write_text("{}"))
    monkeypatch.setattr(evaluate_mod, "evaluate_run", lambda run, **kw: seen.append(("eval",)) or
                        kw["out"].write_text("{}"))
    job = study_jobs("smoke", methods=(OURS,))[0]
    folder = tmp_path / job.folder
    folder.mkdir(parents=True)
    (folder / "config.json").write_text("{}")  # an interrupted run
    result = run_job(job.to_dict(), str(tmp_path))
    assert seen == [("train", True), ("eval",)] and result["status"] == "done"
    (folder / "eval.json").unlink()
    seen.clear()
    assert run_job(job.to_dict(), str(tmp_path))["evaluated"] and seen == [("eval",)]
    assert read_json(folder / "job.json")["status"] == "done"


def test_run_job_records_a_failure_instead_of_raising(tmp_path, monkeypatch):
    def boom(*a, **k):
        raise RuntimeError("replay buffer on fire")

    monkeypatch.setattr(train_mod, "train_run", boom)
    job = study_jobs("smoke", methods=(OURS,))[0]
    result = run_job(job.to_dict(), str(tmp_path), return_files=True)
    assert result["status"] == "failed" and result["message"] == "RuntimeError: replay buffer on fire"
    assert read_json(tmp_path / job.folder / "job.json")["status"] == "failed" and "job.json" in result["files"]


def _fail_rl(job_dict, root, device="cpu", threads=1, return_files=False):
    if job_dict["method"] == "rl":
        return {"status": "failed", "message": "RuntimeError: diverged", "wall_s": 0.1}
    return fakes.fake_work(job_dict, root, device, threads, return_files)


def test_failed_and_unregistered_jobs_are_recorded_and_retried_next_time(tmp_path, monkeypatch):
    root = tmp_path / "study"
    monkeypatch.setattr(methods_mod, "METHODS", {k: v for k, v in methods_mod.METHODS.items() if k != "et-rl"})
    state = reproduce("smoke", root, jobs=1, work=_fail_rl, log=lambda s: None)
    status = {k: (v["status"], v["message"]) for k, v in state["jobs"].items()}
    assert status["two-lane/rl"] == ("failed", "RuntimeError: diverged")
    assert status["exit/et-rl"][0] == "unavailable" and "'et-rl' is not registered" in status["exit/et-rl"][1]
    assert sum(s == "done" for s, _ in status.values()) == 43 - 6 - 6
    assert read_json(root / "study.json")["jobs"]["two-lane/rl"]["status"] == "failed"
    report = (root / "report.md").read_text()
    assert "`two-lane/rl`: failed: RuntimeError: diverged" in report and "`exit/et-rl`: unavailable" in report

    monkeypatch.undo()  # et-rl is registered now and rl no longer fails: only those 12 jobs run
    n = len(fakes.calls(root))
    state = reproduce("smoke", root, jobs=1, work=fakes.fake_work, **QUIET)
    assert sorted(fakes.calls(root)[n:]) == sorted(k for k, v in status.items() if v[0] != "done")
    assert all(v["status"] == "done" for v in state["jobs"].values())


def test_local_executor_runs_jobs_in_parallel_worker_processes(tmp_path):
    root = tmp_path / "study"
    state = reproduce("smoke", root, jobs=2, work=fakes.fake_work, methods=(OURS,), **QUIET)
    assert len(state["jobs"]) == 11 and all(v["status"] == "done" for v in state["jobs"].values())
    assert sorted(fakes.calls(root)) == sorted(state["jobs"])


def test_jobs_spread_round_robin_over_the_gpus_and_otherwise_share_the_given_device():
    assert place_jobs("cuda", 5, gpus=2) == ["cuda:0", "cuda:1", "cuda:0", "cuda:1", "cuda:0"]
    assert place_jobs("cuda", 3, gpus=1) == ["cuda"] * 3  # --jobs N on one GPU: N processes share it
    assert place_jobs("cuda:1", 2, gpus=4) == ["cuda:1"] * 2 and place_jobs("cpu", 2, gpus=0) == ["cpu"] * 2


def test_local_workers_get_each_job_on_its_placed_device(tmp_path, monkeypatch):
    """The CPU equivalent of --device cuda --jobs 2 on a 2-GPU machine: two worker processes, jobs alternating
    between the devices (the stand-in work only records the device it was given)."""
    monkeypatch.setattr(executors, "gpu_count", lambda: 2)
    root = tmp_path / "study"
    jobs = study_jobs("smoke", (OURS,))[:4]
    results = []
    executors.run_local(jobs, root, "cuda", 2, lambda job, r: results.append(r), work=fakes.device_work)
    rows = [json.loads(line) for line in (tmp_path / "study.devices.jsonl").read_text().splitlines()]
    placed = dict(zip([j.id for j in jobs], ["cuda:0", "cuda:1", "cuda:0", "cuda:1"]))
    assert {r["job"]: r["device"] for r in rows} == placed and len(results) == 4
    assert all(r["pid"] != os.getpid() for r in rows)  # in worker processes, not the driver


def _cli(capsys, *argv) -> tuple[int, list[str]]:
    rc = main(["reproduce", *argv])
    return rc, capsys.readouterr().err.strip().splitlines()


def test_bad_input_gives_a_one_line_error(tmp_path, capsys):
    root = tmp_path / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, **QUIET)
    rc, err = _cli(capsys, "--budget", "quick", "--out", str(root))
    assert rc == 2 and len(err) == 1 and "holds a study of budget 'smoke'" in err[0]
    for argv, words in ((["--budget", "huge"], "unknown budget 'huge'"),
                        (["--budget", "smoke", "--executor", "slurm"], "unknown executor 'slurm'"),
                        (["--budget", "smoke", "--methods", "dqn-x"], "'dqn-x'"),
                        ([], "choose a budget")):
        rc, err = _cli(capsys, *argv, "--out", str(tmp_path / "new"))
        assert rc == 2 and len(err) == 1 and words in err[0], (argv, err)
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    rc, err = _cli(capsys, "--budget", "smoke", "--out", str(tmp_path / "busy"))
    assert rc == 2 and len(err) == 1 and "holds no study" in err[0]
    assert json.loads((root / "study.json").read_text())["budget"] == "smoke"


def test_report_only_writes_the_report_of_the_jobs_done_so_far_and_runs_nothing(tmp_path, capsys):
    root = tmp_path / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, methods=(OURS,), **QUIET)
    state = json.loads((root / "study.json").read_text())
    first = next(iter(state["jobs"]))  # as in a study still running: one job not finished yet
    state["jobs"][first]["status"] = "pending"
    (root / "study.json").write_text(json.dumps(state))
    folder = root / study_jobs("smoke", methods=(OURS,))[0].folder
    (folder / "eval.json").unlink()
    (folder / "scalars.csv").write_text("env_steps,steps_per_s\n672,100.0\n")  # half of its 1,344 steps logged
    before, n = (root / "study.json").read_bytes(), len(fakes.calls(root))

    assert main(["reproduce", "--out", str(root), "--report-only"]) == 0
    assert capsys.readouterr().out.strip() == f"report: {root / 'report.md'}"
    report = (root / "report.md").read_text()
    assert f"jobs: {len(state['jobs']) - 1} done, 1 pending" in report
    assert f"`{first}`: pending (672 of 1,344 env steps logged)" in report
    assert (root / "tables").is_dir() and (root / "report.html").exists()
    assert (root / "study.json").read_bytes() == before and len(fakes.calls(root)) == n  # read only, ran nothing

    rc, err = _cli(capsys, "--budget", "quick", "--out", str(root), "--report-only")
    assert rc == 2 and len(err) == 1 and "holds a study of budget 'smoke', not 'quick'" in err[0]
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    for folder in ("new", "busy"):
        rc, err = _cli(capsys, "--out", str(tmp_path / folder), "--report-only")
        assert rc == 2 and len(err) == 1 and "holds no study" in err[0], err
    assert not (tmp_path / "new").exists() and (tmp_path / "busy" / "notes.txt").read_text() == "mine"


def test_a_study_made_with_other_budget_settings_is_refused(tmp_path, monkeypatch):
    import dataclasses

    from highway_srl.study import jobs as study_mod

    root = tmp_path / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, methods=(OURS,), **QUIET)
    monkeypatch.setitem(study_mod.BUDGETS, "smoke", dataclasses.replace(study_mod.BUDGETS["smoke"], steps=3200))
    with pytest.raises(ValueError, match=r"made with other settings \(steps changed since\)"):
        reproduce("smoke", root, jobs=1, work=fakes.fake_work, methods=(OURS,), **QUIET)


def test_a_part_of_the_study_runs_with_other_seeds_and_keeps_them(tmp_path, capsys):
    """`--scenes two-lane --seeds 0` is the study's two-lane column (Group 1, Table 5) at one seed."""
    root = tmp_path / "study"
    state = reproduce("smoke", root, jobs=1, work=fakes.fake_work, scenes=("two-lane",), seeds=(3,),
                      log=lambda s: None)
    assert sorted(state["jobs"]) == sorted(f"two-lane/{m}" for m in
                                           ("moe-rm-srl", "rl", "sr-rl", "rm-rl", "mp-rl", "lm-rl", "et-rl",
                                            "rule-based"))
    assert all(v["job"]["seeds"] == [3] for v in state["jobs"].values())
    saved = read_json(root / "study.json")
    assert saved["budget_config"]["seeds"] == [3] and saved["scenes"] == ["two-lane"]
    assert "seeds 3 (1 run(s)" in (root / "report.md").read_text()
    with pytest.raises(ValueError, match=r"other settings \(seeds changed since\)"):
        reproduce("smoke", root, jobs=1, work=fakes.fake_work, scenes=("two-lane",), seeds=(0, 1), **QUIET)
    for argv, words in ((["--scenes", "three-lane"], "unknown scene(s) 'three-lane'"),
                        (["--seeds", "0,0"], "distinct non-negative")):
        rc, err = _cli(capsys, "--budget", "smoke", *argv, "--out", str(tmp_path / "new"))
        assert rc == 2 and len(err) == 1 and words in err[0], (argv, err)


def test_workers_take_one_thread_unless_omp_num_threads_says_more(monkeypatch):
    """One rule with the CLI (experiments.runs.default_threads): the cores are not divided among workers,
    since a second thread per worker collapses when the cores are shared (docs/benchmarks.md)."""
    from types import SimpleNamespace

    from highway_srl.study.executors import run_local

    job, seen = SimpleNamespace(to_dict=dict), []
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr("os.cpu_count", lambda: 8)
    run_local([job], Path("."), "cpu", 1, lambda _, out: seen.append(out), work=_threads_of)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    run_local([job], Path("."), "cpu", 1, lambda _, out: seen.append(out), work=_threads_of)
    assert seen == [1, 3]


def _threads_of(job_dict, root, device, threads):
    return threads


def test_job_fraction_reads_the_last_logged_step_of_a_running_job(tmp_path):
    from highway_srl.study.jobs import Job
    from highway_srl.study.results import job_fraction

    job = Job("rl", "two-lane", steps=8000)
    assert job_fraction(tmp_path, job) == 0.0  # nothing logged yet
    folder = tmp_path / job.folder
    folder.mkdir(parents=True)
    (folder / "scalars.csv").write_text("env_steps,speed\n2000,5.1\n4000,5.3\n")
    assert job_fraction(tmp_path, job) == 0.5
    (folder / "scalars.csv").write_text("env_steps,speed\n2000,5.1\n12000,5.3\n")
    assert job_fraction(tmp_path, job) == 1.0  # never past the job


def test_study_progress_counts_running_jobs_by_their_logs_and_ends_at_the_total(tmp_path):
    from highway_srl.study.jobs import Job
    from highway_srl.study.runner import StudyProgress

    jobs = [Job("rl", "two-lane", steps=4000), Job("sr-rl", "two-lane", steps=4000)]
    (tmp_path / jobs[0].folder).mkdir(parents=True)
    (tmp_path / jobs[0].folder / "scalars.csv").write_text("env_steps\n2000\n")
    bar = StudyProgress(tmp_path, jobs, enabled=True, interval_s=60.0)
    try:
        assert bar.bar.initial == bar.bar.n == pytest.approx(0.5)  # a resumed job's steps: not this run's rate
        bar.refresh()
        assert bar.bar.n == pytest.approx(0.5)
        for rows in ("1400", "1600"):  # 0.35 then 0.4: float increments would show 0.39999999999999997
            (tmp_path / jobs[0].folder / "scalars.csv").write_text(f"env_steps\n{rows}\n")
            bar.shown = 0.0
            bar.refresh()
        assert "0.4/2" in str(bar.bar)
        bar.job_finished(jobs[0])
        bar.job_finished(jobs[1])
        assert bar.bar.n == pytest.approx(2.0) and bar.bar.n <= bar.bar.total
    finally:
        bar.close()


def test_reproduce_with_progress_writes_job_lines_and_finishes(tmp_path, capsys):
    reproduce("smoke", tmp_path / "study", jobs=1, work=fakes.fake_work, report=False, progress=True)
    err = capsys.readouterr()
    assert "study" in err.err  # the bar is drawn on stderr
    n = len(study_jobs("smoke"))
    assert f"[{n}/{n}]" in err.out  # every job's line, written above the bar


def test_a_worker_ends_when_the_study_process_is_killed(tmp_path):
    # `kill PID` of reproduce left its spawned workers training on, holding their run folders' locks, so
    # the next reproduce recorded those jobs as failed. Workers now end once their parent is gone.
    import signal
    import subprocess
    import sys
    import textwrap

    pid_file = tmp_path / "worker.pid"
    script = textwrap.dedent(f"""
        import multiprocessing as mp, os, time
        from concurrent.futures import ProcessPoolExecutor
        from highway_srl.study.executors import exit_with_parent

        def job(path):
            open(path, "w").write(str(os.getpid()))
            time.sleep(120)

        if __name__ == "__main__":
            with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"), initializer=exit_with_parent,
                                     initargs=(os.getpid(),)) as pool:
                pool.submit(job, {str(pid_file)!r}).result()
    """)
    (tmp_path / "study_proc.py").write_text(script)
    parent = subprocess.Popen([sys.executable, str(tmp_path / "study_proc.py")], cwd=tmp_path,
                              env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    try:
        deadline = time.time() + 60
        while not pid_file.exists() or not pid_file.read_text():
            assert time.time() < deadline and parent.poll() is None, "the worker never started"
            time.sleep(0.2)
        worker = int(pid_file.read_text())
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.time() + 30  # the worker polls its parent every second
        while _alive(worker):
            assert time.time() < deadline, "the orphaned worker kept running"
            time.sleep(0.2)
    finally:
        parent.kill()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_a_second_reproduce_on_one_folder_is_refused_while_report_only_reads_it(tmp_path, capsys):
    # two reproduce on one --out would both run the pending jobs and overwrite each other's study.json
    import signal
    import subprocess
    import sys

    root = tmp_path / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, **QUIET)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from pathlib import Path; from highway_srl.experiments.runs "
         "import lock_run\nwith lock_run(Path(sys.argv[1])):\n    print('held', flush=True); time.sleep(120)",
         str(root)], stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    try:
        assert holder.stdout.readline().strip() == "held"
        rc, err = _cli(capsys, "--budget", "smoke", "--out", str(root))
        assert rc == 2 and err == [f"highway-srl: error: --out {str(root)!r} is in use by another reproduce (pid {holder.pid})"]
        assert main(["reproduce", "--out", str(root), "--report-only"]) == 0  # only reads: takes no lock
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    finally:
        holder.kill()
    state = reproduce("smoke", root, jobs=1, work=fakes.fake_work, **QUIET)  # a killed holder leaves no lock
    assert len(state["invocations"]) == 2
