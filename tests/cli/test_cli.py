"""The command line: clear one-line errors for bad input, and the commands a user types work."""

import json
import subprocess
import sys

import pytest

from highway_srl.cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["bench", "sim", "--scenario", "roundabout", "--envs", "2", "--steps", "1"], "unknown scenario 'roundabout'"),
        (["bench", "sim", "--traffic", "G", "--envs", "2", "--steps", "1"], "unknown traffic level 'G'"),
        (["bench", "sim", "--device", "cuda:7", "--envs", "2", "--steps", "1"], "cuda:7"),
        (["bench", "sim", "--device", "tpu", "--envs", "2", "--steps", "1"], "tpu"),
        (["train", "--method", "ppo", "--steps", "10", "--out", "x"], "unknown method 'ppo'"),
        (["train", "--scenario", "roundabout", "--steps", "10", "--out", "x"], "unknown scenario"),
        (["train", "--seeds", "1,1", "--steps", "10", "--out", "x"], "distinct"),
        (["evaluate", "does/not/exist"], "does not exist"),
        (["render", "--policy", "teleport", "--out", "x.gif"], "unknown policy 'teleport'"),
        (["evaluate", ".", "--traffic", "A..Z"], "unknown traffic range"),
        (["bench", "sim", "--envs", "2", "--steps", "1", "--processes", "3"], "between 1 and num_envs (2)"),
        (["bench", "sim", "--envs", "2", "--steps", "1", "--processes", "2", "--compile"], "processes > 1"),
        (["bench", "train", "--envs", "2", "--steps", "1", "--processes", "2"], "--processes is for bench sim"),
    ],
)
def test_bad_input_gives_one_line_error_naming_the_value(capsys, argv, needle, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, *argv)
    assert code == 2
    assert needle in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_negative_counts_are_rejected_by_the_parser(capsys):
    assert main(["bench", "sim", "--envs", "-3"]) == 2
    assert "positive integer" in capsys.readouterr().err


def test_bench_sim_prints_json(capsys):
    code, out, _ = run(capsys, "bench", "sim", "--envs", "8", "--steps", "5", "--json")
    result = json.loads(out)
    assert code == 0 and result["env_steps_per_s"] > 0 and result["envs"] == 8


def test_bench_sim_in_worker_processes_prints_json(capsys):
    code, out, _ = run(capsys, "bench", "sim", "--envs", "8", "--steps", "5", "--processes", "2", "--json")
    result = json.loads(out)
    assert code == 0 and result["env_steps_per_s"] > 0 and result["processes"] == 2


def test_render_writes_gif_and_png(capsys, tmp_path):
    code, out, _ = run(capsys, "render", "--scenario", "merge", "--steps", "12", "--out", str(tmp_path / "m.gif"))
    assert code == 0
    assert (tmp_path / "m.gif").stat().st_size > 1000 and (tmp_path / "m.png").stat().st_size > 1000


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "run"
    assert main(["train", "--traffic", "A", "--steps", "160", "--envs", "8", "--learning-starts", "64",
                 "--quiet", "--out", str(out)]) == 0
    return out


def test_train_then_evaluate_writes_metrics(capsys, trained_run, tmp_path):
    capsys.readouterr()
    code, out, _ = run(capsys, "evaluate", str(trained_run), "--traffic", "A,B", "--episodes", "3", "--json",
                       "--out", str(tmp_path / "eval.json"))
    report = json.loads(out)
    assert code == 0 and set(report["levels"]) == {"A", "B"}
    assert 0.0 <= report["levels"]["A"]["C_r"]["value"] <= 1.0
    assert json.loads((trained_run / "metrics.json").read_text())["env_steps_per_seed"] == 160


def test_train_refuses_to_overwrite_a_run(capsys, trained_run):
    code, _, err = run(capsys, "train", "--steps", "10", "--out", str(trained_run))
    assert code == 2 and "already holds a run" in err


def test_corrupt_checkpoint_is_a_clear_error_and_touches_nothing(capsys, trained_run, tmp_path):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(trained_run, broken)
    model = broken / "model" / "model.safetensors"
    model.write_bytes(model.read_bytes()[:100])
    before = sorted(p.name for p in broken.rglob("*"))
    code, _, err = run(capsys, "evaluate", str(broken), "--episodes", "2")
    assert code == 2 and "model.safetensors" in err and "Traceback" not in err
    assert sorted(p.name for p in broken.rglob("*")) == before


def test_checkpoint_of_another_method_is_refused(capsys, trained_run, tmp_path):
    import shutil

    other = tmp_path / "other"
    shutil.copytree(trained_run, other)
    meta = json.loads((other / "model" / "meta.json").read_text())
    meta["method"] = "rl"
    (other / "model" / "meta.json").write_text(json.dumps(meta))
    code, _, err = run(capsys, "evaluate", str(other), "--episodes", "2")
    assert code == 2 and "'rl'" in err


def test_config_with_unknown_keys_is_refused(capsys, trained_run, tmp_path):
    import shutil

    other = tmp_path / "keys"
    shutil.copytree(trained_run, other)
    config = json.loads((other / "config.json").read_text())
    config["config"]["learning_rate_typo"] = 1
    (other / "config.json").write_text(json.dumps(config))
    code, _, err = run(capsys, "evaluate", str(other), "--episodes", "2")
    assert code == 2 and "learning_rate_typo" in err


def test_evaluating_on_another_scenario_is_refused(capsys, trained_run):
    code, _, err = run(capsys, "evaluate", str(trained_run), "--scenario", "merge", "--episodes", "2")
    assert code == 2 and "trained on scenario 'two-lane'" in err


def test_console_script_reports_errors_without_traceback():
    exe = [sys.executable, "-m", "highway_srl.cli", "bench", "sim", "--scenario", "nowhere"]
    proc = subprocess.run(exe, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "unknown scenario 'nowhere'" in proc.stderr and "Traceback" not in proc.stderr


def test_train_help_lists_profile_adversary_and_replay_ratio(capsys):
    assert main(["train", "--help"]) == 0
    text = capsys.readouterr().out
    assert "--profile" in text and "--replay-ratio" in text and "--adversary" in text


def test_a_runs_config_records_profile_adversary_and_replay_ratio(capsys, tmp_path):
    out = tmp_path / "run"
    assert main(["train", "--method", "rl", "--traffic", "A", "--steps", "64", "--envs", "4", "--learning-starts",
                 "32", "--profile", "safe", "--adversary", "mild", "--replay-ratio", "0.5", "--quiet",
                 "--out", str(out)]) == 0
    config = json.loads((out / "config.json").read_text())["config"]
    assert (config["profile"], config["adversary"], config["replay_ratio"]) == ("safe", "mild", 0.5)
    capsys.readouterr()
    code, text, _ = run(capsys, "evaluate", str(out), "--episodes", "2", "--json", "--out", str(tmp_path / "e.json"))
    assert code == 0 and (json.loads(text)["profile"], json.loads(text)["adversary"]) == ("safe", "mild")
    code, text, _ = run(capsys, "evaluate", str(out), "--episodes", "2", "--json", "--profile", "paper",
                        "--out", str(tmp_path / "f.json"))
    assert code == 0 and json.loads(text)["profile"] == "paper"


def test_train_static_is_recorded_and_compile_without_the_static_step_is_a_one_line_error(capsys, tmp_path):
    out = tmp_path / "run"
    assert main(["train", "--method", "rl", "--traffic", "A", "--steps", "64", "--envs", "4", "--learning-starts",
                 "32", "--static", "--quiet", "--out", str(out)]) == 0
    config = json.loads((out / "config.json").read_text())["config"]
    assert (config["static"], config["compile"]) == (True, False)
    capsys.readouterr()
    code, _, err = run(capsys, "train", "--steps", "64", "--compile", "--no-static", "--out", str(tmp_path / "x"))
    assert code == 2 and "compile needs the static step" in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()  # refused before any folder is made
