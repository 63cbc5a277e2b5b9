"""Benchmark and study records say which of torch's CPU kernels ran and MKL's reproducible mode (they move
the figures and the last bits); provenance names a commit only for a highway-srl checkout."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import torch

from highway_srl import __version__
from highway_srl.experiments import runs
from highway_srl.experiments.bench import bench_sim
from highway_srl.study.runner import machine

PACKAGE = Path(runs.__file__).resolve().parents[1]


def test_bench_and_study_records_name_the_cpu_kernels_and_the_mkl_mode(monkeypatch):
    monkeypatch.setenv("MKL_CBWR", "COMPATIBLE")
    record = bench_sim("two-lane", "C", envs=2, steps=2, device="cpu")["machine"]
    assert record["cpu_kernels"] == torch.backends.cpu.get_cpu_capability() == machine()["cpu_kernels"] != ""
    assert record["mkl_cbwr"] == machine()["mkl_cbwr"] == "COMPATIBLE"
    monkeypatch.delenv("MKL_CBWR")
    assert bench_sim("two-lane", "C", envs=2, steps=2, device="cpu")["machine"]["mkl_cbwr"] == machine()["mkl_cbwr"] == ""


def _git(folder, *args):
    subprocess.run(["git", "-C", str(folder), "-c", "user.name=t", "-c", "user.email=t@t", *args], check=True,
                   capture_output=True)


def _provenance_of(package_parent) -> dict:
    """provenance() as a process that imports highway_srl from package_parent records it."""
    code = "import json; from highway_srl.experiments.runs import provenance; print(json.dumps(provenance()))"
    env = {**os.environ, "PYTHONPATH": str(package_parent), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True,
                         cwd=package_parent)  # not the current folder, which may hold this checkout
    return json.loads(out.stdout)


def test_a_copy_of_the_package_inside_another_repository_records_no_commit(tmp_path):
    """A user's own git repository with highway_srl inside it (a vendored copy, a virtual environment in
    the repository): its HEAD is not highway-srl's commit, so only the version is recorded."""
    repo = tmp_path / "user-project"
    shutil.copytree(PACKAGE, repo / "vendor" / "highway_srl", ignore=shutil.ignore_patterns("__pycache__"))
    (repo / "pyproject.toml").write_text('[project]\nname = "user-project"\n')
    _git(tmp_path, "init", "-q", str(repo))
    _git(repo, "add", "-A")
    _git(repo, "commit", "-q", "-m", "user code")
    record = _provenance_of(repo / "vendor")
    assert record == {"version": __version__, "commit": None}
    assert runs.commit(repo / "vendor" / "highway_srl") is None


def test_a_highway_srl_checkout_records_its_commit(tmp_path):
    repo = tmp_path / "highway-srl"
    (repo / "highway_srl").mkdir(parents=True)
    (repo / "pyproject.toml").write_text('[project]\nname = "highway-srl"\n')
    _git(tmp_path, "init", "-q", str(repo))
    _git(repo, "add", "-A")
    _git(repo, "commit", "-q", "--allow-empty", "-m", "ours")
    head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert runs.commit(repo / "highway_srl") == head
    (repo / "pyproject.toml").write_text('[project]\nname = "highway-srl"\nversion = "0"\n')
    assert runs.commit(repo / "highway_srl") == head + "-dirty"
