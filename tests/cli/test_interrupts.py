"""Ctrl-C and `kill` at any moment of a command, with worker processes or without: one line on stderr, exit
status 130 (Ctrl-C) or 143 (kill), no traceback from the command or a worker, and no process left behind.

Each command runs in its own session, so that a signal to its process group is what Ctrl-C in a terminal
does (every process of the foreground group, workers included). The signal goes once the command has
reached a given point (a file, a worker process), never after a fixed sleep."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cli_runs import TRAIN

ROOT = Path(__file__).resolve().parents[2]
STUDY = ["reproduce", "--budget", "smoke", "--jobs", "2", "--methods", "moe-rm-srl,rl", "--scenes", "two-lane"]

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads child processes from /proc")


def as_from_a_terminal() -> None:
    """In the child before it runs: Ctrl-C's default action, as a shell at a terminal leaves it. A suite started
    in the background of a non-interactive shell (`cmd &`) inherits SIGINT ignored, and Python started so
    keeps ignoring it, which is not what these tests are about."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def children(pid: int) -> list[int]:
    """The processes whose parent is pid."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # it ended meanwhile
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def stopped(argv, ready, sig=signal.SIGINT, whole_group=True, timeout=240, entry=("-m", "highway_srl.cli"),
            path=()) -> tuple[int, str]:
    """Start the CLI with argv (through entry, with the folders path first on PYTHONPATH), wait until ready()
    holds, send sig (to its group, like Ctrl-C, or to the command alone, like `kill PID`); its exit status and
    stderr once every process of its group is gone."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([*map(str, path), str(ROOT)]), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, *map(str, entry), *map(str, argv)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=as_from_a_terminal)
    try:
        deadline = time.monotonic() + timeout
        while not ready(proc.pid):
            assert proc.poll() is None, f"ended before it was ready: {proc.stderr.read()}"
            assert time.monotonic() < deadline, "not ready in time"
            time.sleep(0.05)
        if whole_group:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=timeout)
        while group_alive(proc.pid) and time.monotonic() < deadline:  # its workers end with it
            time.sleep(0.05)
        assert not group_alive(proc.pid), "a worker outlived the command"
        return proc.returncode, err
    finally:
        if group_alive(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)


def one_line(err: str, line: str) -> None:
    assert "Traceback" not in err and "Error" not in err, err
    lines = [x for x in err.replace("\r", "\n").splitlines() if x.strip() and not x.startswith("study:")]
    assert len(lines) == 1 and lines[0].startswith(line), err


def test_ctrl_c_in_training_is_one_line_with_the_way_to_resume(tmp_path):
    out = tmp_path / "run"
    code, err = stopped([*TRAIN, "--steps", "1000000", "--out", out],
                        lambda pid: (out / "config.json").exists())
    assert code == 130
    one_line(err, "highway-srl: interrupted; continue from")


def test_kill_of_a_training_is_one_line_and_status_143(tmp_path):
    out = tmp_path / "run"
    code, err = stopped([*TRAIN, "--steps", "1000000", "--out", out], lambda pid: (out / "config.json").exists(),
                        sig=signal.SIGTERM, whole_group=False)
    assert code == 143
    one_line(err, "highway-srl: terminated; continue from")


def test_ctrl_c_in_bench_with_worker_processes_is_one_line():
    code, err = stopped(["bench", "sim", "--processes", "2", "--envs", "64", "--steps", "1000000"],
                        lambda pid: len(children(pid)) >= 1)
    assert code == 130
    one_line(err, "highway-srl: interrupted")


def test_ctrl_c_while_the_study_workers_start_is_one_line(tmp_path):
    out = tmp_path / "study"
    # the workers are there but still importing (a job's first file comes seconds later)
    code, err = stopped([*STUDY, "--out", out], lambda pid: len(children(pid)) >= 2)
    assert code == 130
    one_line(err, "highway-srl: interrupted")


# a sitecustomize that stalls each of a study's spawned workers as it starts, its signals held (as while
# it imports torch); it says so in a file
STALLED_WORKER = """import os, sys, time
if any("spawn_main" in arg for arg in sys.orig_argv):
    open(os.path.join(os.environ["HIGHWAY_SRL_TEST_STALLED"], str(os.getpid())), "w").close()
    time.sleep(600)
"""


def test_ctrl_c_ends_a_study_whose_workers_are_still_starting(tmp_path, monkeypatch):
    # the workers never finish starting: a study that waited for them would outlast the timeout
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(STALLED_WORKER)
    marks = tmp_path / "stalled"
    marks.mkdir()
    monkeypatch.setenv("HIGHWAY_SRL_TEST_STALLED", str(marks))
    out = tmp_path / "study"
    code, err = stopped([*STUDY, "--out", out], lambda pid: any(marks.iterdir()), path=[site])
    assert code == 130
    one_line(err, "highway-srl: interrupted")


def test_kill_of_a_study_ends_its_running_jobs_with_one_line(tmp_path):
    out = tmp_path / "study"
    code, err = stopped([*STUDY, "--out", out], lambda pid: any((out / "runs").glob("*/*/.lock")),
                        sig=signal.SIGTERM, whole_group=False)
    assert code == 143
    one_line(err, "highway-srl: terminated")


# a gymnasium whose import stops midway (it says so in a file): the signal comes while highway_srl imports,
# before the command's main runs
STALLED_IMPORT = """import os, time
open(os.environ["HIGHWAY_SRL_TEST_IMPORTING"], "w").close()
time.sleep(600)
"""
# what pip writes as the console script `highway-srl`
CONSOLE_SCRIPT = """import sys
from highway_srl.cli import main
sys.exit(main())
"""


@pytest.mark.parametrize("entry,sig,status,word", [
    ("module", signal.SIGINT, 130, "interrupted"), ("script", signal.SIGINT, 130, "interrupted"),
    ("module", signal.SIGTERM, 143, "terminated")])
def test_a_signal_while_python_imports_is_one_line(tmp_path, monkeypatch, entry, sig, status, word):
    stalled = tmp_path / "stalled" / "gymnasium"
    stalled.mkdir(parents=True)
    (stalled / "__init__.py").write_text(STALLED_IMPORT)
    mark = tmp_path / "importing"
    monkeypatch.setenv("HIGHWAY_SRL_TEST_IMPORTING", str(mark))
    script = tmp_path / "bin" / "highway-srl"
    script.parent.mkdir()
    script.write_text(CONSOLE_SCRIPT)
    code, err = stopped(["--version"], lambda pid: mark.exists(), sig=sig, whole_group=sig == signal.SIGINT,
                        entry=("-m", "highway_srl.cli") if entry == "module" else (script,), path=[stalled.parent])
    assert code == status
    one_line(err, f"highway-srl: {word}")


def test_importing_the_library_leaves_the_signals_to_the_program():
    code = ("import signal, highway_srl; print(signal.getsignal(signal.SIGINT) is signal.default_int_handler, "
            "signal.getsignal(signal.SIGTERM) is signal.SIG_DFL)")
    done = subprocess.run([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, timeout=240, preexec_fn=as_from_a_terminal)
    assert done.stdout.split() == ["True", "True"], done.stderr


def test_a_falsify_run_with_worker_processes_ends_without_a_word_from_them():
    # the pool's end sends its workers SIGTERM; forked with the command's handlers, those still waiting for a
    # batch printed tracebacks (in about two runs of three with these eight batches: so three runs)
    argv = ["falsify", "--scenes", "two-lane", "--levels", "C,F", "--modes", "nominal", "--episodes", "16",
            "--envs", "4", "--steps", "8", "--processes", "2"]
    for _ in range(3):
        done = subprocess.run([sys.executable, "-m", "highway_srl.cli", *argv], capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}, timeout=240)
        assert done.returncode == 0 and "Traceback" not in done.stderr and "Terminated" not in done.stderr, done.stderr
        assert done.stdout.startswith("32 episodes (safe profile, uniform ego)"), done.stdout
