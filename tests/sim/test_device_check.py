"""The GPU check script runs end to end on the CPU at toy sizes, and the package imports without gymnasium."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

BLOCK_GYMNASIUM = """
import sys

import pytest
class Block:
    def find_spec(self, name, path=None, target=None):
        if name == "gymnasium" or name.startswith("gymnasium."):
            raise ImportError("gymnasium is hidden")
sys.meta_path.insert(0, Block())
"""


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}


def test_package_simulator_and_trainer_import_without_gymnasium():
    code = BLOCK_GYMNASIUM + "import highway_srl\nfrom highway_srl.sim import World\n" \
        "from highway_srl.agents.trainer import Trainer\nimport highway_srl.experiments.bench\nprint('imported')\n"
    done = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "imported"


def test_device_check_without_a_gpu_runs_the_cpu_smoke_and_writes_every_part_and_the_projections(tmp_path):
    out = tmp_path / "check.json"
    runner = BLOCK_GYMNASIUM + "import runpy, sys\nsys.argv = sys.argv[1:]\n" \
        "runpy.run_path(sys.argv[0], run_name='__main__')\n"
    cmd = [sys.executable, "-c", runner, str(ROOT / "scripts" / "device_check.py"), "--out", str(out)]
    done = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    assert report == json.loads(done.stdout) and report["cpu_smoke"] and "no CUDA device" in done.stderr
    statuses = {name: part["status"] for name, part in report["parts"].items()}
    assert statuses and set(statuses.values()) == {"ok"}, report["parts"]
    trains = {f"train-moe-rm-srl-{n}-seeds{how}" for n in (1, 10) for how in ("", "-compiled")}
    assert {"gpu-tests", *trains} <= set(statuses)
    assert any(name.startswith("sim-") and name.endswith("-compiled") for name in statuses)
    copies = report["parts"]["train-moe-rm-srl-10-seeds-x2"]["result"]
    assert copies["copies"] == 2 and len(copies["env_steps_per_s"]) == 2
    assert copies["aggregate_env_steps_per_s"] >= copies["conservative_env_steps_per_s"] > 0
    cpu = report["parts"]["sim-two-lane-C-4-cpu-processes"]["result"]
    assert cpu["processes"] == 2 and cpu["processes_env_steps_per_s"] > 0 and cpu["over_one_process"] > 0
    projected = report["projections"]
    assert projected["study_h"] > 0 and projected["eager"]["study_h"] > 0 and projected["compiled"]["study_h"] > 0
    assert report["parts"]["gpu-tests"]["result"]["returncode"] == 0
    assert "passed" in report["parts"]["gpu-tests"]["result"]["summary"]


def test_only_keeps_the_parts_named_by_prefix_and_names_the_parts_when_none_matches():
    spec = importlib.util.spec_from_file_location("device_check", ROOT / "scripts" / "device_check.py")
    check = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(check)
    parts = check.plan(smoke=False)
    assert check.select(parts, "") == parts
    only = "sim-two-lane-C-65536-compiled, train-moe-rm-srl-10-seeds-compiled"
    chosen = [p["name"] for p in check.select(parts, only)]
    assert chosen == ["train-moe-rm-srl-10-seeds-compiled", "sim-two-lane-C-65536-compiled"]
    with pytest.raises(SystemExit, match="names no part; the parts: gpu-tests"):
        check.select(parts, "nothing-")
