"""The falsifier (experiments/falsify.py) and the decision trace's ego-avoidable verdict on simulated
collisions: a forced cut-in at 0 m is unavoidable, the ego accelerating into a stopped car is avoidable, a
short search finds the paper profile's lane-change cycle and nothing under the safe profile, and every
case it saves replays to the same collision."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
import torch

from highway_srl.experiments import falsify as fz
from highway_srl.experiments.collisions import LANE_CHANGE_CYCLE, DecisionTrace
from highway_srl.rules import SafetyLayer
from highway_srl.constants import VEHICLE_LENGTH_M
from highway_srl.rules.avoidable import FORBIDDEN_ACTION, RAN_INTO, SIDE_SWIPE, ego_avoidable, stopping_distance_steps
from highway_srl.rules.safe_actions import ACTIONS, FASTER, IDLE, LANE_CHANGE, SLOWER
from highway_srl.sim import World

SHORT = dict(levels=("F",), modes=(False,), episodes=32, envs=32, steps=48, seed=0)  # ~2 s per profile


def _world_with(ego_speed: float, **sv) -> World:
    """One two-lane env: the ego at x = 100 in lane 0, SV 1 set by `sv` (state fields), the rest far ahead."""
    w = World("two-lane", "C", num_envs=1, seed=0)
    s = w.state
    n = s.x.shape[1]
    s.x[:, 0], s.y[:, 0], s.heading[:, 0], s.v[:, 0] = 100.0, 0.0, 0.0, ego_speed
    s.x[:, 1:] = 600.0 + 20.0 * torch.arange(1, n, dtype=torch.float32)
    s.y[:, 1:], s.heading[:, 1:], s.v[:, 1:] = 0.0, 0.0, 1.0
    s.lane[:] = s.target_lane[:] = 0
    s.forced[:] = s.lane_change[:] = False
    for name, value in sv.items():
        getattr(s, name)[0, 1] = value
    return w


def _drive(world, pick, profile="safe") -> list[dict]:
    trace = DecisionTrace(SimpleNamespace(action_names=ACTIONS, safe_mask=lambda model: model.mask))
    fz.drive(world, SafetyLayer(world.road, profile=profile), pick, trace, limit=120)
    return trace.records


def test_a_forced_cut_in_at_zero_metres_is_unavoidable_even_for_the_best_response():
    """An SV at 2 m/s forced into the ego's lane with its rear bumper level with the ego's front (gap 0 m),
    the ego at 9 m/s braking whenever the rule layer allows it: the SV meets the ego's side."""
    def brake_first(step, view):
        allowed = view.primary.mask[0]
        return torch.tensor([next(a for a in (SLOWER, IDLE, FASTER, LANE_CHANGE) if allowed[a])])

    world = _world_with(9.0, x=105.0, y=3.5, v=2.0, v0=2.0, lane=1, target_lane=0, forced=True)
    [record] = _drive(world, brake_first)
    assert (record["kind"], record["ego_avoidable"], record["reason"]) == ("side", False, SIDE_SWIPE)
    assert all(r["action"] in r["allowed"] for r in record["decisions"])


def test_the_ego_accelerating_into_a_stopped_car_is_avoidable():
    world = _world_with(10.0, x=130.0, v=0.0, v0=0.0)  # a car standing 25 m ahead (it crawls off slowly)
    [record] = _drive(world, lambda step, view: torch.tensor([FASTER]))
    assert (record["kind"], record["ego_avoidable"], record["reason"]) == ("front", True, FORBIDDEN_ACTION)
    # without the rule layer (every action allowed) the physics alone says the same: it had room to stop
    unshielded = [{**r, "allowed": list(ACTIONS)} for r in record["decisions"]]
    assert ego_avoidable("front", False, False, unshielded) == (True, RAN_INTO)
    # the first decision the trace kept the car's offsets for (the reset state before the first step is not
    # kept): the gap still exceeded the ego's braking distance there
    first = next(r for r in unshielded if r["dx"] is not None)
    assert first["v_sv"] < 0.5 and first["dx"] - VEHICLE_LENGTH_M > stopping_distance_steps(first["v"]) > 8.0


def test_a_short_search_finds_the_lane_change_cycle_under_paper_and_nothing_under_safe(tmp_path):
    paper = fz.falsify(fz.FalsifySettings(profile="paper", **SHORT), tmp_path / "paper")
    assert paper["episodes"] == 32 and paper["by_decision"][LANE_CHANGE_CYCLE] >= 1
    assert paper["ego_avoidable"] >= 1 and paper["ego_avoidable"] + paper["unavoidable"] == paper["collisions"]
    cycle = [c for c in paper["cases"] if LANE_CHANGE_CYCLE in c["cause"] and c["ego_avoidable"]]
    assert cycle and len({c["cause"] for c in paper["cases"]}) == len(paper["cases"])  # one case per cause
    safe = fz.falsify(fz.FalsifySettings(profile="safe", **SHORT))
    assert (safe["collisions"], safe["ego_avoidable"], safe["cases"]) == (0, 0, [])
    assert safe["ego_avoidable_rate_upper_95"] == pytest.approx(3 / 32)
    for case in paper["cases"]:  # every saved case replays to its collision, in the same step
        result = fz.replay_case(fz.load_case(case["path"]))
        assert result["confirmed"] and result["cause"] == case["cause"] and result["all_allowed"]
    replayed_safe = fz.replay_case(fz.load_case(cycle[0]["path"]), "safe")
    assert not replayed_safe["confirmed"]  # brake_while_changing: the same actions no longer end in it


def test_the_cli_writes_cases_and_replays_them(tmp_path, capsys):
    from highway_srl.cli import main

    out = tmp_path / "found"
    args = ["--levels", "F", "--modes", "nominal", "--episodes", "32", "--envs", "32", "--steps", "48"]
    assert main(["falsify", *args, "--profile", "paper", "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report == json.loads((out / "report.json").read_text())
    path = report["cases"][0]["path"]
    assert main(["falsify", "--replay", path]) == 0
    assert "confirmed" in capsys.readouterr().out
    gif = tmp_path / "case.gif"
    assert main(["falsify", "--replay", path, "--gif", str(gif)]) == 0
    assert gif.stat().st_size > 0 and gif.with_suffix(".png").exists()
    assert main(["falsify", "--replay", path, "--gif", str(tmp_path / "case.mp4")]) == 2
    (tmp_path / "bad.json").write_text(json.dumps({**json.loads(open(path).read()), "actions": [7]}))
    assert main(["falsify", "--replay", str(tmp_path / "bad.json")]) == 2
    assert main(["falsify", "--modes", "sideways"]) == 2
    assert main(["falsify", "--policy", "reckless"]) == 2
    assert main(["falsify", *args, "--out", str(out)]) == 2  # a folder with a report is not written over
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 5 and "must end in .gif" in err[0] and "actions must be" in err[1] and "--modes" in err[2]
    assert "already holds" in err[4]


def test_every_policy_takes_only_allowed_actions():
    world = World("two-lane", "F", False, 64, "cpu", 3)
    layer = SafetyLayer(world.road, profile="paper")
    gen = torch.Generator().manual_seed(0)
    view = layer.observe(world)
    for _ in range(6):
        for policy in fz.POLICIES:
            action = fz.choose(policy, view, gen)
            assert bool(view.primary.mask.gather(1, action[:, None]).all())
        world.step(*layer.act(action))
        view = layer.observe(world)


def test_greedy_ttc_picks_the_allowed_action_with_the_soonest_contact():
    # SV1 10 m ahead at 5, SV2 20 m ahead at 10, SV3 5 m behind at 12, SV4 8 m behind at 3; the ego at 8 m/s
    model = SimpleNamespace(gaps_m=torch.tensor([[10.0, 20.0, 5.0, 8.0]]), vehicles=SimpleNamespace(
        vx=torch.tensor([[5.0, 10.0, 12.0, 3.0]])), mask=torch.ones(1, 4, dtype=torch.bool))
    ttc = fz.predicted_ttc(model, torch.tensor([8.0]))
    assert ttc[0].tolist() == pytest.approx([10 / 3.4375, 10 / 3, 5 / 4.75, fz.NO_CONTACT_S])
    view = SimpleNamespace(primary=model, snapshot=SimpleNamespace(ego_vx=torch.tensor([8.0])))
    assert int(fz.choose("greedy-ttc", view, torch.Generator())) == SLOWER  # braking in front of SV3
    model.mask[0, SLOWER] = False
    assert int(fz.choose("greedy-ttc", view, torch.Generator())) == FASTER


def test_rate_upper_bound():
    assert fz.rate_upper_bound(0, 100) == pytest.approx(0.03)
    assert fz.rate_upper_bound(1, 10) == pytest.approx(0.3942, abs=1e-4)  # exact one-sided Clopper-Pearson
    assert fz.rate_upper_bound(5, 5) == 1.0
    assert fz.binomial_cdf(1, 10, fz.rate_upper_bound(1, 10)) == pytest.approx(0.05, abs=1e-9)
    with pytest.raises(ValueError, match="0 <= k <= n"):
        fz.rate_upper_bound(3, 2)


def test_evaluate_reports_the_verdict_of_every_collision_in_eval_json(tmp_path):
    from highway_srl.cli import main

    run = tmp_path / "run"
    assert main(["train", "--method", "mp-rl", "--traffic", "F", "--envs", "4", "--steps", "64",
                 "--learning-starts", "32", "--quiet", "--out", str(run)]) == 0
    assert main(["evaluate", str(run), "--traffic", "F", "--episodes", "16", "--out", str(tmp_path / "eval.json")]) == 0
    collisions = json.loads((tmp_path / "eval.json").read_text())["levels"]["F"]["collisions"]
    assert collisions["collisions"] >= 1  # the paper profile at level F (measured: 11 of 16)
    assert collisions["ego_avoidable"] + collisions["unavoidable"] == collisions["collisions"]
    assert sum(collisions["by_reason"].values()) == collisions["collisions"]


def test_processes_split_the_batches_and_merge_to_the_same_report(tmp_path):
    """--processes: 4 batches of 4 episodes (paper profile, so there are collisions and cases) in one process
    and in three workers give the same report, cases included (but for the record of the run itself)."""
    settings = dict(profile="paper", levels=("F",), modes=(False,), episodes=16, envs=4, steps=48, seed=0)
    one = fz.falsify(fz.FalsifySettings(**settings), tmp_path / "one")
    three = fz.falsify(fz.FalsifySettings(**settings), tmp_path / "three", processes=3)
    assert one["collisions"] >= 1 and one["cases"]
    assert (one["processes"], three["processes"]) == (1, 3) and one["wall_s"] >= 0 and "commit" in one
    strip = lambda report: {**report, "cases": [{**c, "path": c["path"].split("/")[-1]} for c in report["cases"]],  # noqa: E731
                            "processes": None, "wall_s": None}
    assert strip(three) == strip(one)
    with pytest.raises(ValueError, match="processes must be a positive integer"):
        fz.falsify(fz.FalsifySettings(**settings), processes=0)
