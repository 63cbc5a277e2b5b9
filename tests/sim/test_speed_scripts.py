"""The speed-measuring scripts run end to end at toy sizes and refuse bad input with one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, *args], env=env, capture_output=True, text=True, timeout=300, cwd=ROOT)


def test_ab_sim_compares_batch_sizes_and_settings_of_one_checkout():
    done = _run("scripts/ab_sim.py", ".", ".", "--envs", "2,3", "--processes", "1", "--rounds", "2", "--block", "2",
                "--env-a", "HIGHWAY_SRL_DEFAULT_MALLOC=1", "--env-b", "AB_WORLD_PROCESSES=2")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert [(s["envs"], s["env"]) for s in out["sides"]] == [
        (2, ["HIGHWAY_SRL_DEFAULT_MALLOC=1"]), (3, ["HIGHWAY_SRL_DEFAULT_MALLOC=1"]),
        (2, ["AB_WORLD_PROCESSES=2"]), (3, ["AB_WORLD_PROCESSES=2"])]
    assert all(s["mean_env_steps_per_s"] > 0 and len(s["process_medians"]) == 1 for s in out["sides"])
    assert out["sides"][0]["over_first"] == 1.0


def test_ab_sim_bad_input_is_one_line():
    for args in (["--envs", "4,x", "."], ["."], ["/nonexistent", "."], [".", ".", "--env-b", "NOEQUALS"]):
        done = _run("scripts/ab_sim.py", *args)
        assert done.returncode == 2 and "Traceback" not in done.stderr
        assert done.stderr.strip().splitlines()[-1].startswith("ab_sim.py: error:")


def test_ops_per_step_counts_the_step_by_function_and_times_it():
    done = _run("scripts/ops_per_step.py", "--envs", "2", "--steps", "2", "--times")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    # the step's own functions are where its operations are; the total is their sum
    assert {"mobil_lane_changes", "lateral", "idm_accel_fast"} <= set(out["by_function"])
    assert abs(sum(out["by_function"].values()) - out["ops_per_step"]) < 1.0
    assert 100 < out["ops_per_step"] < 5000
    # --times: the wall time per step and the profiler's busiest operations, each with its calls per step
    assert out["wall_ms_per_step"] > 0 and 0 < len(out["by_op"]) <= 20
    assert all(v["calls"] > 0 and v["self_ms"] >= 0 for v in out["by_op"].values())


def test_processes_timing_times_every_slice_and_the_hand_over():
    done = _run("scripts/processes_timing.py", "--envs", "6", "--processes", "3", "--steps", "5")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert len(out["slice_busy_ms"]) == 3 and all(b > 0 for b in out["slice_busy_ms"])
    # the caller's step contains every slice's: what is beyond the slowest is the hand-over, never negative
    assert out["step_ms"] >= out["slowest_slice_ms"] >= max(out["slice_busy_ms"])
    assert out["beyond_slowest_ms"] >= 0 and out["env_steps_per_s"] > 0
    bad = _run("scripts/processes_timing.py", "--envs", "2", "--processes", "3")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "2 <= --processes <= --envs" in bad.stderr


def test_step_phases_times_the_step_by_function():
    done = _run("scripts/step_phases.py", "--envs", "4", "--steps", "3", "--warmup", "1")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    parts = out["ms_per_step_by_function"]
    assert {"find_neighbours", "mobil_lane_changes", "recycle", "ego_collision"} <= set(parts)
    # each function's own time: the parts add up to the step, less the loop around it
    assert 0.5 * out["ms_per_step"] < sum(parts.values()) <= out["ms_per_step"] * 1.01


def test_step_phases_bad_input_is_one_line():
    done = _run("scripts/step_phases.py", "--envs", "0")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1].startswith("step_phases.py: error:")


def test_rule_layer_cost_times_an_addition_off_and_on():
    done = _run("scripts/rule_layer_cost.py", "--option", "lanes_by_body", "--scenario", "two-lane", "--envs", "4",
                "--rounds", "2", "--repeats", "2")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["option"] == "lanes_by_body" and out["ms_per_observe_off"] > 0 and out["ms_per_observe_on"] > 0
    done = _run("scripts/rule_layer_cost.py", "--option", "hold_lateral", "--scenario", "two-lane", "--envs", "4",
                "--rounds", "2", "--repeats", "2", "--act")  # an addition that works in act
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["ms_per_observe_act_off"] > 0 and out["ms_per_observe_act_on"] > 0
    bad = _run("scripts/rule_layer_cost.py", "--option", "standstill_gap_m")  # not a boolean addition
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()[-1]) < 400
