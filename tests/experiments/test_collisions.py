"""The collision census (experiments/collisions.py): each collision's kind from constructed geometry, and the
census of real deployment episodes agrees with their collision count."""

from __future__ import annotations

import pytest
import torch

from highway_srl.agents.registry import make_method
from highway_srl.experiments.collisions import Census, classify
from highway_srl.experiments.evaluate import EVAL_SEED_BASE, run_episodes
from highway_srl.sim import World


def _placed_world() -> World:
    """Four envs, every SV parked far ahead except SV 1, placed against the ego in each env's own way."""
    w = World("two-lane", "C", num_envs=4, seed=0)
    s = w.state
    n = s.x.shape[1]
    s.x[:, 0], s.y[:, 0], s.heading[:, 0], s.v[:, 0] = 100.0, 0.0, 0.0, 3.0
    s.lane[:, 0] = s.target_lane[:, 0] = 0
    s.x[:, 1:] = 400.0 + 20.0 * torch.arange(1, n, dtype=torch.float32)
    s.y[:, 1:], s.heading[:, 1:], s.v[:, 1:] = 0.0, 0.0, 1.0
    s.lane[:, 1:] = s.target_lane[:, 1:] = 0
    s.forced[:] = False
    s.x[0, 1] = 104.5  # env 0: bumpers overlap, SV ahead: the ego ran into it
    s.x[1, 1] = 95.5  # env 1: SV behind: it ran into the ego
    s.x[2, 1], s.y[2, 1], s.lane[2, 1], s.target_lane[2, 1] = 101.0, 1.6, 0, 0  # env 2: beside, 1.6 m off
    s.forced[2, 1] = True  # ... in a forced cut-in
    s.target_lane[3, 0] = 1  # env 3: no SV touches the ego (a road collision), which is changing lanes
    s.y[3, 0] = 0.8
    return w


def test_kinds_and_who_changed_lanes_from_the_geometry():
    records = classify(_placed_world(), torch.arange(4))
    assert [r["kind"] for r in records] == ["front", "rear", "side", "road"]
    assert [r["sv"] for r in records] == ["keeping lane", "keeping lane", "forced cut-in", None]
    assert [r["ego_changing"] for r in records] == [False, False, False, True]
    assert records[0]["ego_speed"] == 3.0 and records[0]["sv_speed"] == 1.0 and records[3]["sv_speed"] is None


def test_the_nearest_of_several_overlapping_svs_is_the_one_reported():
    w = _placed_world()
    w.state.x[0, 2], w.state.y[0, 2] = 95.2, 0.0  # env 0 also touched from behind, 0.2 m deep (ahead: 0.5 m)
    assert classify(w, torch.tensor([0]))[0]["kind"] == "front"


def test_census_of_deployment_episodes_counts_every_collision_once():
    # the rule-based driver against the paper's adversary: its collisions are forced cut-ins (issue 12)
    census = Census()
    world = World("two-lane", "C", True, 48, "cpu", EVAL_SEED_BASE, adversary="paper")
    results = run_episodes(world, make_method("rule-based", "two-lane", 1), None, after_step=census.level("C"))
    summary = census.summary()["C"]
    assert summary["collisions"] == int(results["collided"].sum()) > 0
    assert all(r["sv"] == "forced cut-in" for r in census.records["C"])
    assert summary["sv_forced_cut_in"] == summary["collisions"]
    assert set(summary["by_kind"]) <= {"front", "rear", "side", "road"}
    quiet = Census()
    run_episodes(World("two-lane", "A", num_envs=4, seed=EVAL_SEED_BASE), make_method("rule-based", "two-lane", 1),
                 None, after_step=quiet.level("A"))
    assert quiet.summary() == {"A": {"collisions": 0, "by_kind": {}, "by_detail": {}, "while_ego_changing": 0,
                                     "sv_changing": 0, "sv_forced_cut_in": 0, "mean_ego_speed": None,
                                     "mean_sv_speed": None}}


def test_the_census_script_reports_a_trained_runs_levels_and_refuses_bad_input_in_one_line(tmp_path):
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    from highway_srl.cli import main

    root = Path(__file__).resolve().parents[2]
    run = tmp_path / "run"
    assert main(["train", "--traffic", "A", "--envs", "4", "--steps", "64", "--learning-starts", "32", "--quiet",
                 "--out", str(run)]) == 0
    env = {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1"}
    script = [sys.executable, str(root / "scripts" / "collision_census.py")]
    done = subprocess.run([*script, str(run), "--traffic", "A,F", "--episodes", "3"], env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert set(out["levels"]) == {"A", "F"} and out["profile"] == "paper"
    for level in out["levels"].values():  # the census and evaluate's C_r count the same episodes
        assert level["collisions"] == round((1 - level["C_r"]) * 3) == sum(level["by_kind"].values())
    saved = json.loads((run / "eval.json").read_text()) if (run / "eval.json").exists() else None
    assert saved is None or "collisions" in saved["levels"]["C"]  # train's own evaluation carries it too
    done = subprocess.run([*script, str(tmp_path / "nothing")], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1].startswith("collision_census.py: error:")


def _closing_on_a_slower_leader() -> World:
    """One env: the ego at 10 m/s in lane 0, SV 1 15 m ahead (centres) cruising at 7 m/s (its desired speed,
    no lane changes of its own), lane 1 free, the other SVs parked 500 m on."""
    w = World("two-lane", "C", num_envs=1, seed=0)
    s = w.state
    n = s.x.shape[1]
    s.x[:, 0], s.y[:, 0], s.heading[:, 0], s.v[:, 0] = 100.0, 0.0, 0.0, 10.0
    s.x[:, 1:] = 600.0 + 20.0 * torch.arange(1, n, dtype=torch.float32)
    s.y[:, 1:], s.heading[:, 1:], s.v[:, 1:] = 0.0, 0.0, 1.0
    s.lane[:] = s.target_lane[:] = 0
    s.forced[:] = s.lane_change[:] = False
    s.x[0, 1], s.v[0, 1], s.v0[0, 1] = 115.0, 7.0, 7.0
    return w


def test_repeated_lane_change_behind_a_slower_leader_is_the_paper_mappings_gap_and_the_trace_names_it():
    """What the trained MP-RL found (docs/results.md, the paper-budget baselines): LaneChange every step with
    the car ahead too close (R*1 = 0) and the other lane free. Table 1 allows it (R*2 ∧ R*4); once the ego's
    corner is within ε_p of the line (m*_L,EV = 1) Eq. 35 with R*3 = R*4 = 1 returns C_ID, so the ego turns
    back, m*_L,EV drops, Eq. 34 starts the change again: it never leaves its lane, LaneChange holds the speed,
    and it runs into the leader. brake_while_changing (safe profile) brakes through the same decisions."""
    from types import SimpleNamespace

    from highway_srl.experiments.collisions import (
        CLASS_WINDOW, DECISION_CLASSES, LANE_CHANGE_CYCLE, VERDICT_WINDOW, DecisionTrace, show_decisions)
    from highway_srl.rules import SafetyLayer
    from highway_srl.rules.safe_actions import LANE_CHANGE

    method = make_method("mp-rl", "two-lane", 1)  # its safe mask (Table 1) and action names
    for brake in (False, True):
        world = _closing_on_a_slower_leader()
        layer = SafetyLayer(world.road, profile="paper", brake_while_changing=brake)
        trace, view, alive, hit = DecisionTrace(method), layer.observe(world), torch.ones(1, dtype=torch.bool), None
        for t in range(80):
            assert bool(view.primary.mask[0, LANE_CHANGE])  # Table 1 allows it in every step
            action = torch.tensor([LANE_CHANGE])
            events = world.step(*layer.act(action))
            trace(view, SimpleNamespace(decision=SimpleNamespace(action=action, use_second=None), events=events), alive)
            view = layer.observe(world)
            assert int(world.ego_lane[0]) == 0  # the change never completes
            if bool(events.collision[0]):
                hit = t
                break
        if brake:
            assert hit is None and trace.records == []
        else:
            assert hit is not None and hit < 40 and float(world.state.v[0, 0]) == pytest.approx(10.0, abs=1e-3)
            [record] = trace.records
            assert (record["env"], record["step"], record["class"]) == (0, hit, LANE_CHANGE_CYCLE)
            # the last VERDICT_WINDOW decisions of the episode
            assert [r["step"] for r in record["decisions"]] == list(range(max(0, hit - VERDICT_WINDOW + 1), hit + 1))
            assert all(r["action"] == "LaneChange" and "LaneChange" in r["allowed"] and not r["r1"]
                       for r in record["decisions"][-CLASS_WINDOW:])  # the decisions the class reads
            assert trace.counts() == {**dict.fromkeys(DECISION_CLASSES, 0), LANE_CHANGE_CYCLE: 1}
            assert show_decisions(record).splitlines()[-1].endswith("executed LaneChange")


def test_decision_classes_from_constructed_decisions():
    from highway_srl.experiments.collisions import CREEP, FORBIDDEN, LANE_CHANGE_CYCLE, OTHER, classify_decisions

    def row(action, allowed, r1=True, gap1=10.0):
        return {"action": action, "allowed": allowed, "r1": r1, "gap1": gap1}

    cycle = row("LaneChange", ["Slower", "LaneChange"], r1=False, gap1=1.0)
    creep = row("Faster", ["Faster", "Idle", "Slower"], gap1=0.2)
    assert classify_decisions([row("Idle", ["Idle"]), cycle]) == LANE_CHANGE_CYCLE
    assert classify_decisions([row("LaneLeft", ["Slower", "LaneLeft"], r1=False)]) == LANE_CHANGE_CYCLE  # A's
    assert classify_decisions([creep, row("Slower", ["Slower"], r1=False, gap1=0.1)]) == CREEP
    assert classify_decisions([cycle, creep, row("Faster", ["Slower"], r1=False)]) == FORBIDDEN  # first
    assert classify_decisions([row("Slower", ["Slower"], r1=False, gap1=0.1), row("Idle", ["Idle"])]) == OTHER


def test_the_trace_script_agrees_with_evaluate_and_refuses_bad_input_in_one_line(tmp_path, capsys):
    import importlib.util
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    from highway_srl.cli import main

    root = Path(__file__).resolve().parents[2]
    run = tmp_path / "run"
    assert main(["train", "--method", "mp-rl", "--traffic", "F", "--envs", "4", "--steps", "64",
                 "--learning-starts", "32", "--quiet", "--out", str(run)]) == 0
    spec = importlib.util.spec_from_file_location("collision_trace", root / "scripts" / "collision_trace.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    capsys.readouterr()
    assert script.main([str(run), "--traffic", "F", "--episodes", "6", "--show", "1"]) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)["levels"]["F"]
    assert out["collisions"] == 0 or "executed" in captured.err  # --show printed the first collision's decisions
    env = {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1"}
    census = subprocess.run([sys.executable, str(root / "scripts" / "collision_census.py"), str(run), "--traffic",
                             "F", "--episodes", "6"], env=env, capture_output=True, text=True, timeout=300)
    assert census.returncode == 0, census.stderr
    level = json.loads(census.stdout)["levels"]["F"]
    assert out["collisions"] == level["collisions"] == sum(out["by_decision"].values())
    assert out["C_r"] == pytest.approx(level["C_r"], abs=1e-4)
    for bad, says in ((["--set", "brake=true"], "unknown option 'brake'"), (["--set", "straddle_grouping"], "OPTION=VALUE"),
                      (["--traffic", "G"], "unknown traffic level"), (["--episodes", "0"], "positive"),
                      (["--set", "standstill_gap_m=x"], "neither true/false nor a number")):
        with pytest.raises(SystemExit) as exit_:
            script.main([str(run), *bad])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and "Traceback" not in err, bad
        last = err.strip().splitlines()[-1]
        assert last.startswith("collision_trace.py: error:") and says in last, last
    with pytest.raises(SystemExit):
        script.main([str(tmp_path / "nothing")])
    assert "does not exist" in capsys.readouterr().err
