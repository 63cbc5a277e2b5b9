"""The falsifier's cross-entropy search (experiments/scenario_search.py) and the scenario parameters it sets
(experiments/scenario_params.py): the refit moves toward the elite, no parameters leave the spawn as it
is, an env edited in a batch starts as it does alone, a short search under the paper profile finds its
known holes and every case replays, and bad input is one line."""

from __future__ import annotations

import json
from dataclasses import fields

import pytest
import torch

from highway_srl.experiments import falsify as fz
from highway_srl.experiments import scenario_search as ss
from highway_srl.experiments.scenario_params import KNOBS, check_parameters, scenario_world
from highway_srl.sim import World

EVERY_KNOB = {"gap_scale": 1.4, "sv_speed_mps": 0.5, "ego_speed_mps": 5.75, "aggressive": 1.0, "normal": 0.0,
              "cautious": 0.5, "cut_in_prob": 1.0, "trigger_offset_m": 7.0}


def _same_state(a: World, b: World, envs=slice(None)) -> bool:
    return all(torch.equal(getattr(a.state, f.name)[envs], getattr(b.state, f.name)) for f in fields(a.state))


def test_the_refit_moves_the_distribution_toward_the_elite():
    """Scores that favour level F and a high first knob: the refit puts more mass on F, moves the knob's
    mean up and narrows it; the other categorical dimension, scored alike, stays near even."""
    dist = ss.Distribution.initial(fz.FalsifySettings(levels=("C", "F"), modes=(False, True)))
    draws = dist.sample(200, torch.Generator().manual_seed(0))
    scores = draws["level"].double() + draws["z"][:, 0]
    new = dist.refit(draws, scores, ss.SearchSettings(samples=200, elite=0.2, smoothing=0.7))
    # every elite draw is at F: 0.3 x 0.5 + 0.7 x 1
    assert new.probs["level"].tolist() == pytest.approx([0.15, 0.85])
    assert new.probs["level"][0] >= ss.FLOOR  # never shut for good
    assert new.mean[0] > dist.mean[0] + 0.1 and new.std[0] < dist.std[0]
    assert abs(float(new.probs["adversarial"][0]) - 0.5) < 0.2
    assert torch.equal(dist.mean, torch.full((len(KNOBS),), 0.5, dtype=torch.float64))  # the old one unchanged


def test_no_parameters_leave_the_spawn_bit_for_bit_and_an_edited_env_starts_alike_alone():
    plain = World("two-lane", "F", True, 3, "cpu", [5, 9, 11], adversary="paper")
    assert _same_state(plain, scenario_world("two-lane", "F", True, [5, 9, 11], 320, "paper", [{}, {}, {}]))
    batch = scenario_world("two-lane", "F", True, [5, 9, 11], 320, "paper", [{}, EVERY_KNOB, {}])
    alone = scenario_world("two-lane", "F", True, [9], 320, "paper", [EVERY_KNOB])
    assert _same_state(batch, alone, slice(1, 2)) and not _same_state(plain, alone, slice(1, 2))
    assert torch.equal(batch.state.x[0], plain.state.x[0]) and torch.equal(batch.state.style[2], plain.state.style[2])
    s = alone.state
    assert float(s.v[0, 0]) == 5.75 and bool((s.style[0, 1:] != 1).all())  # the "normal" weight is 0
    assert bool((s.trigger_offset[0, 1:] == 7.0).all()) and bool((s.adversarial_prob[0, 1:] == 1.0).all())
    ahead = plain.state.x[1, 1:] - plain.state.x[1, :1]
    assert torch.allclose(s.x[0, 1:] - s.x[0, :1], 1.4 * ahead) and bool((s.v[0, 1:] <= 6.0).all())


def test_a_short_search_under_paper_finds_its_holes_and_every_case_replays(tmp_path):
    settings = fz.FalsifySettings(profile="paper", levels=("C", "F"), modes=(False,), steps=48, seed=0)
    report = ss.ce_search(settings, ss.SearchSettings(iterations=2, samples=16), tmp_path / "ce")
    assert report["episodes"] == 32 and len(report["iterations"]) == 2
    assert report["ego_avoidable"] >= 1 and len(report["cases"]) == report["ego_avoidable"]
    assert json.loads(json.dumps(report)) == json.loads((tmp_path / "ce" / "report.json").read_text())
    assert "ran into the car ahead with room to stop" in report["by_reason"]  # a known hole of the printed rules
    for listed in report["cases"]:
        case = fz.load_case(listed["path"])
        assert set(case.parameters) == set(KNOBS) and case.env == 0
        result = fz.replay_case(case)
        assert result["confirmed"] and result["cause"] == listed["cause"] and result["ego_avoidable"]
    again = ss.ce_search(settings, ss.SearchSettings(iterations=2, samples=16))
    assert {k: v for k, v in again.items() if k != "cases"} == {k: v for k, v in report.items() if k != "cases"}


def test_bad_parameters_and_settings_are_one_line_errors(tmp_path):
    with pytest.raises(ValueError, match=r"gap_scale must be a number in \[1, 1.5\]"):
        check_parameters({"gap_scale": 3.0})
    with pytest.raises(ValueError, match="unknown scenario parameter 'wind'"):
        check_parameters({"wind": 1.0})
    with pytest.raises(ValueError, match="all three style weights"):
        check_parameters({"aggressive": 1.0})
    with pytest.raises(ValueError, match="above 0"):
        check_parameters({"aggressive": 0.0, "normal": 0.0, "cautious": 0.0})
    with pytest.raises(ValueError, match="iterations must be a positive integer"):
        ss.SearchSettings(iterations=0).check()
    with pytest.raises(ValueError, match=r"elite must be in \(0, 1\]"):
        ss.SearchSettings(elite=0.0).check()
    case = tmp_path / "case.json"
    case.write_text(json.dumps({"scene": "two-lane", "level": "F", "adversarial": False, "adversary": "paper",
                                "profile": "paper", "seed": 0, "env": 0, "steps": 8, "actions": [0], "cause": "x",
                                "ego_avoidable": True, "parameters": {"gap_scale": -1}}))
    with pytest.raises(ValueError, match="case.json: scenario parameter gap_scale"):
        fz.load_case(case)


def test_the_cli_takes_search_ce_and_rejects_what_does_not_go_with_it(tmp_path, capsys):
    from highway_srl.cli import main

    assert main(["falsify", "--help"]) == 0
    assert "--search {breadth,ce}" in capsys.readouterr().out
    out = tmp_path / "ce"
    args = ["falsify", "--search", "ce", "--iterations", "1", "--samples", "8", "--levels", "F", "--steps", "24",
            "--modes", "nominal", "--profile", "paper"]
    assert main([*args, "--out", str(out)]) == 0
    assert "cross-entropy search" in capsys.readouterr().out and (out / "report.json").exists()
    assert main(["falsify", "--iterations", "3"]) == 2
    assert main(["falsify", "--search", "ce", "--episodes", "3"]) == 2
    assert main(["falsify", "--search", "ce", "--elite", "1.5"]) == 2
    assert main(["falsify", "--search", "ce", "--samples", "4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and "only with --search ce" in err[0] and "go with --search breadth" in err[1]
    assert "--elite" in err[2] and "at least 2 scenarios" in err[3]
