"""`highway-srl transfer`: train in ours, deploy the same policy in every simulator; resume; clear errors."""

from __future__ import annotations

import csv
import json

import pytest

from highway_srl.backends import available_backends
from highway_srl.cli import main
from highway_srl.experiments.evaluate import evaluate_run
from highway_srl.study.transfer import TransferSettings, run_transfer

SIMS = available_backends()  # CI installs both extras; elsewhere the missing ones are left out
SMALL = TransferSettings(steps=320, envs=4, episodes=2, learning_starts=64, batch_size=32, replay_ratio=0.25)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    root = tmp_path_factory.mktemp("transfer") / "t"
    run_transfer(root, SMALL, methods=("moe-rm-srl", "rl"), scenes=("merge",), simulators=SIMS, jobs=1,
                 log=lambda s: None)
    return root


def test_every_method_is_deployed_in_every_simulator_on_the_same_episodes(study):
    rows = list(csv.DictReader((study / "transfer.csv").open()))
    assert {(r["method"], r["simulator"]) for r in rows} == {(m, s) for m in ("moe-rm-srl", "rl") for s in SIMS}
    for r in rows:
        assert r["episodes"] == "2" and 0.0 <= float(r["C_r"]) <= 1.0 and 0.0 <= float(r["R_s"]) <= 1.0
        assert float(r["C_r_low"]) <= float(r["C_r"]) <= float(r["C_r_high"])
    # the 'ours' column is the ordinary evaluation of the run, episode seeds included
    run = study / "runs" / "merge" / "moe-rm-srl"
    again = evaluate_run(run, traffics=["C"], episodes=2)["levels"]["C"]
    ours = next(r for r in rows if r["method"] == "moe-rm-srl" and r["simulator"] == "ours")
    assert float(ours["C_r"]) == pytest.approx(again["C_r"]["value"])
    assert float(ours["speed"]) == pytest.approx(again["avg_speed"]["value"], rel=1e-5)
    for sim in SIMS:
        report = json.loads((run / ("eval.json" if sim == "ours" else f"eval-{sim}.json")).read_text())
        assert report["backend"] == sim and report["method"] == "moe-rm-srl"
    md = (study / "transfer.md").read_text()
    assert "| Merging | MoE-RM-SRL |" in md and "| Merging | RL |" in md and "320 env steps" in md


def test_a_finished_study_runs_nothing_again_and_other_settings_are_refused(study):
    stamps = {p: p.stat().st_mtime_ns for p in study.glob("runs/*/*/eval*.json")}
    lines = []
    run_transfer(study, SMALL, methods=("moe-rm-srl", "rl"), scenes=("merge",), simulators=SIMS, jobs=1,
                 log=lines.append)
    assert "2 done already, 0 to run" in lines[0]
    assert {p: p.stat().st_mtime_ns for p in study.glob("runs/*/*/eval*.json")} == stamps
    with pytest.raises(ValueError, match=r"other settings \(episodes\)"):
        run_transfer(study, TransferSettings(**{**SMALL.__dict__, "episodes": 3}), scenes=("merge",),
                     simulators=SIMS, log=lambda s: None)


def test_bad_input_gives_a_one_line_error(tmp_path, capsys):
    for argv, words in ((["--scenes", "ring-road"], "unknown scene 'ring-road'"),
                        (["--methods", "ppo"], "unknown method 'ppo'"),
                        (["--simulators", "carla"], "unknown simulator 'carla'"),
                        (["--episodes", "0"], "--episodes: expected a positive integer"),
                        (["--episodes", str(10**12)], "use fewer --episodes"),  # refused before training
                        (["--steps", "-5"], "--steps must be positive")):
        rc = main(["transfer", *argv, "--out", str(tmp_path / "new")])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and words in err[0], (argv, err)
    assert not (tmp_path / "new").exists()


KIND = "highway-srl transfer study"
DAMAGED_STATES = {  # transfer.json's text: what the one line must say
    "{}": "transfer.json: kind is missing",
    "[]": "transfer.json is damaged (not a JSON object: [])",
    "null": "transfer.json is damaged (not a JSON object: null)",
    '{"kind": "highway-srl transfer': "transfer.json is not valid JSON (Unterminated string",
    "not json\n": "transfer.json is not valid JSON (Expecting value at line 1)",
    '{"kind": "a study", "settings": {}, "jobs": {}}': "is no transfer study (its kind is 'a study')",
    f'{{"kind": "{KIND}", "settings": [], "jobs": {{}}}}': "transfer.json: settings must be a JSON object, got []",
    f'{{"kind": "{KIND}", "settings": {{}}, "jobs": null}}': "transfer.json: jobs must be a JSON object, got null",
    f'{{"kind": "{KIND}", "settings": {{}}, "jobs": {{"a": []}}}}': "transfer.json: jobs.a must be a JSON object",
    f'{{"kind": "{KIND}", "settings": {{}}, "jobs": {{"a": {{"status": 1}}}}}}':
        "transfer.json: jobs.a: status must be a string, got 1",
    f'{{"kind": "{KIND}", "settings": {{}}, "jobs": {{}}, "wall_s": NaN}}': "wall_s must be a finite number, got nan",
}


@pytest.mark.parametrize("text", DAMAGED_STATES)
def test_a_damaged_transfer_json_is_one_line_and_nothing_is_written(tmp_path, capsys, text):
    root = tmp_path / "t"
    root.mkdir()
    (root / "transfer.json").write_text(text)
    rc = main(["transfer", "--steps", "320", "--envs", "4", "--episodes", "2", "--scenes", "merge", "--out", str(root)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and DAMAGED_STATES[text] in err, err
    assert [p.name for p in root.iterdir()] == ["transfer.json"] and (root / "transfer.json").read_text() == text


@pytest.mark.parametrize("name, damage, words", [
    ("eval.json", lambda d: d["levels"]["C"]["C_r"].update(value=1.5), "levels.C.C_r: value must be a number from 0 to 1"),
    ("eval.json", lambda d: d.update(levels=[]), "levels must be a non-empty JSON object, got []"),
    ("metrics.json", lambda d: d.pop("wall_s"), "metrics.json: wall_s is missing"),
    ("transfer-job.json", lambda d: d.update(eval_s={"ours": None}), "eval_s: ours must be a finite number, got null"),
])
def test_a_damaged_file_of_a_job_stops_the_study_before_anything_is_written(study, tmp_path, name, damage, words):
    import shutil

    copy = tmp_path / "t"
    shutil.copytree(study, copy)
    path = copy / "runs" / "merge" / "rl" / name
    data = json.loads(path.read_text())
    damage(data)
    path.write_text(json.dumps(data))
    before = {p: p.read_bytes() for p in copy.rglob("*") if p.is_file()}
    with pytest.raises(ValueError, match="^" + str(path).replace(".", r"\.")) as err:
        run_transfer(copy, SMALL, methods=("moe-rm-srl", "rl"), scenes=("merge",), simulators=SIMS, jobs=1,
                     log=lambda s: None)
    assert words in str(err.value) and "\n" not in str(err.value)
    assert {p: p.read_bytes() for p in copy.rglob("*") if p.is_file()} == before
