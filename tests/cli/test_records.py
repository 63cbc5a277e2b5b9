"""Run-folder records read back: finite numbers or a stop, one schema for every file, nothing lost. Each bad
case is one line on stderr with exit status 2 and every file that was there unchanged (hashes before/after)."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file
from cli_runs import TRAIN, hashes, interrupted_run, one_line_error, run

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.train_config import TrainConfig, check_config
from highway_srl.cli import main
from highway_srl.experiments import train as train_mod, training_log


def _copy(run_dir: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "r"
    shutil.copytree(run_dir, copy)
    return copy


def _edit_config(folder: Path, edit) -> None:
    data = json.loads((folder / "config.json").read_text())
    edit(data["config"])
    (folder / "config.json").write_text(json.dumps(data))


# ---------------------------------------------------------------- finite numbers or a stop
@pytest.mark.parametrize("setting, value, needle", [
    ("lr", float("nan"), "dqn.lr"), ("lr", float("inf"), "dqn.lr"), ("gamma", -0.5, "dqn.gamma"),
    ("batch_size", 0, "dqn.batch_size"), ("hidden", -5, "dqn.hidden"), ("hidden", "256", "dqn.hidden"),
    ("adam_betas", (1.5, 0.9), "dqn.adam_betas"),
])
def test_a_dqn_setting_no_run_can_have_is_one_line_naming_it(setting, value, needle):
    with pytest.raises(ValueError, match=needle):
        check_config(TrainConfig(dqn=DQNConfig(**{setting: value})))


@pytest.mark.parametrize("edit, needle", [
    (lambda c: c["dqn"].__setitem__("lr", float("nan")), "dqn.lr"),
    (lambda c: c["dqn"].__setitem__("lr", float("inf")), "dqn.lr"),
    (lambda c: c.__setitem__("steps", float("inf")), "steps"),
    (lambda c: c.__setitem__("steps", "4000"), "steps"),
    (lambda c: c.__setitem__("dqn", None), "dqn"),
    (lambda c: c["dqn"].__setitem__("batch_size", 0), "dqn.batch_size"),
    (lambda c: c.__setitem__("seeds", None), "seeds"),
    (lambda c: c.__setitem__("seeds", [2**63]), "seeds"),
    (lambda c: c["dqn"].__setitem__("hidden", -5), "dqn.hidden"),
])
@pytest.mark.parametrize("command", ["evaluate", "resume"])
def test_a_config_json_no_run_can_have_is_one_line(capsys, finished_run, tmp_path, edit, needle, command):
    run_dir = _copy(finished_run, tmp_path)
    (run_dir / "metrics.json").unlink()  # so that --resume does not stop at "finished"
    _edit_config(run_dir, edit)
    before = hashes(run_dir)
    argv = {"evaluate": ["evaluate", run_dir, "--episodes", "1", "--out", tmp_path / "e.json"],
            "resume": ["train", "--resume", "--quiet", "--out", run_dir]}[command]
    code, _, err = run(capsys, *argv)
    one_line_error(code, err, needle)
    assert "config.json" in err and hashes(run_dir) == before


def test_training_stops_at_the_first_non_finite_weight_naming_step_and_expert(tmp_path, monkeypatch):
    """NaN put into expert E2,1's weights at env step 96: the row at 160 (LOG_EVERY 80) stops the run."""
    monkeypatch.setattr(training_log, "LOG_EVERY", 80)
    real_step = train_mod.Trainer.step

    def poisoned(self):
        if self.env_steps == 96:
            self.learner.online.flat.data[1, 0] = float("nan")  # member 1 of MoE-RM-SRL: E2,1
        return real_step(self)

    monkeypatch.setattr(train_mod.Trainer, "step", poisoned)
    cfg = TrainConfig(traffic="A", steps=400, envs=8, dqn=DQNConfig(learning_starts=64))
    with pytest.raises(train_mod.TrainingDiverged, match=r"env step 160: the weights of expert E2,1 \(seed 0\)"
                                                          r" became NaN or infinite after step 80"):
        train_mod.train_run(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "model").exists() and not (tmp_path / "run" / "metrics.json").exists()


def test_training_stops_at_a_non_finite_loss(tmp_path, monkeypatch):
    monkeypatch.setattr(training_log, "LOG_EVERY", 80)
    real_log = training_log.TrainingLog.log
    monkeypatch.setattr(training_log.TrainingLog, "log", lambda self, t: {**real_log(self, t), "loss": float("inf")})
    cfg = TrainConfig(traffic="A", steps=400, envs=8, dqn=DQNConfig(learning_starts=64))
    with pytest.raises(train_mod.TrainingDiverged, match="env step 80: the loss, Q-value or TD error"):
        train_mod.train_run(cfg, tmp_path / "run", progress=False)


def test_evaluate_refuses_a_model_with_non_finite_weights(capsys, finished_run, tmp_path):
    run_dir = _copy(finished_run, tmp_path)
    path = run_dir / "model" / "model.safetensors"
    tensors = load_file(path)
    tensors["learner.online.flat"][0, 3] = float("nan")
    save_file(tensors, path)
    before = hashes(run_dir)
    code, _, err = run(capsys, "evaluate", run_dir, "--episodes", "1", "--out", tmp_path / "e.json")
    one_line_error(code, err, "learner.online.flat holds NaN or infinite values")
    assert hashes(run_dir) == before and not (tmp_path / "e.json").exists()


def test_resume_refuses_a_checkpoint_with_non_finite_weights(capsys, tmp_path, monkeypatch):
    out, code, _ = interrupted_run(tmp_path, monkeypatch, capsys)
    assert code == 130
    path = out / "resume" / "model.safetensors"
    tensors = load_file(path)
    tensors["learner.online.flat"][0, 0] = float("inf")
    save_file(tensors, path)
    before = hashes(out)
    code, _, err = run(capsys, "train", "--resume", "--quiet", "--out", out)
    one_line_error(code, err, "learner.online.flat holds NaN or infinite values")
    assert hashes(out) == before
    assert torch.isinf(load_file(path)["learner.online.flat"][0, 0])


# ---------------------------------------------------------------- one schema for the files read back
@pytest.fixture(scope="module")
def killed_run(tmp_path_factory):
    """A run of 1 env killed by Ctrl-C after 1,000 steps: its checkpoint at 700 covers two episodes (320
    steps each or fewer) and three scalars.csv rows (LOG_EVERY 200); a third episode and more rows follow."""
    out = tmp_path_factory.mktemp("killed") / "run"
    real_step = train_mod.Trainer.step

    def dying(self):
        if self.env_steps >= 1000:
            raise KeyboardInterrupt
        return real_step(self)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(train_mod.Trainer, "step", dying)
        patch.setattr(training_log, "LOG_EVERY", 200)
        code = main(TRAIN + ["--envs", "1", "--steps", "1400", "--checkpoint-every", "700", "--out", str(out)])
    assert code == 130 and train_mod.last_checkpoint_step(out) == 700
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 3
    return out


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory, finished_run):
    """A finished run as demo --steps 160 --envs 8 reuses it (its metrics.json is read back)."""
    out = tmp_path_factory.mktemp("demo")
    shutil.copytree(finished_run, out / "run")
    _edit_config(out / "run", lambda c: c.update(replay_ratio=0.25))
    return out


def _json_edit(edit):
    """A damage to a JSON file: edit(data) changes the parsed object in place."""
    def damage(path: Path) -> None:
        data = json.loads(path.read_text())
        edit(data)
        path.write_text(json.dumps(data))
    return damage


def _line_edit(n: int, edit):
    """A damage to line n (0-based) of a text file: edit(line) -> its replacement."""
    def damage(path: Path) -> None:
        lines = path.read_text().splitlines(keepends=True)
        lines[n] = edit(lines[n])
        path.write_text("".join(lines))
    return damage


def _row_edit(n: int, edit):
    """A damage to the JSON object on line n of a JSON-lines file."""
    return _line_edit(n, lambda line: json.dumps(edit(json.loads(line))) + "\n")


def _garbage(path: Path) -> None:  # a line of garbage after the first
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:1] + ["\x00garbage}{\n"] + lines[1:]))


def _truncated(path: Path) -> None:  # cut at half its bytes
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _csv_cell(row: int, column: int, value: str):
    def edit(line: str) -> str:
        cells = line.rstrip("\n").split(",")
        cells[column] = value
        return ",".join(cells) + "\n"
    return _line_edit(row, edit)


RESUME = ("train", "--resume", "--quiet", "--out")
DAMAGES = {  # file: {kind of damage: (damage, needle of the one-line error)}
    "config.json": {
        "wrong type": (_json_edit(lambda d: d["config"].__setitem__("steps", "4000")), "steps"),
        "missing field": (_json_edit(lambda d: d["config"].pop("envs")), "envs"),
        "NaN": (_json_edit(lambda d: d["config"]["dqn"].__setitem__("lr", float("nan"))), "dqn.lr"),
        "garbage line": (_garbage, "not valid JSON"),
        "truncated": (_truncated, "not valid JSON"),
    },
    "resume/meta.json": {
        "wrong type": (_json_edit(lambda d: d["log"].__setitem__("step", "600")), "log: step must be a non-negative integer"),
        "missing field": (_json_edit(lambda d: d["log"].pop("usage")), "log: usage must be"),
        "NaN": (_json_edit(lambda d: d.__setitem__("wall_s", float("nan"))), "wall_s"),
        "garbage line": (_garbage, "not valid JSON"),
        "truncated": (_truncated, "not valid JSON"),
    },
    "episodes.jsonl": {
        "wrong type": (_row_edit(0, lambda r: {**r, "collision": "no"}), "line 1 is damaged: the row: collision"),
        "missing field": (_line_edit(1, lambda _: '{"seed": 0}\n'), "line 2 is damaged: the row: step is missing"),
        "NaN": (_row_edit(1, lambda r: {**r, "return": float("nan")}), "line 2 is damaged: the row: return"),
        "garbage line": (_garbage, "line 2 is damaged: not JSON"),
        "truncated": (_truncated, "the checkpoint counted 2"),
    },
    "scalars.csv": {
        "wrong type": (_csv_cell(1, 3, "abc"), "line 2 is damaged: epsilon is not a number"),
        "missing field": (_line_edit(2, lambda line: line.split(",", 1)[0] + "\n"), "line 3 is damaged: 1 cells"),
        "NaN": (_csv_cell(2, 3, "nan"), "line 3 is damaged: epsilon is nan"),
        "garbage line": (_garbage, "line 2 is damaged"),
        "truncated": (_truncated, "the file was cut or edited"),
    },
}
DEMO_DAMAGES = {
    "wrong type": (_json_edit(lambda d: d["mean"].__setitem__("T_c", "0.9")), "mean: T_c"),
    "missing field": (_json_edit(lambda d: d.pop("env_steps_per_seed")), "env_steps_per_seed is missing"),
    "NaN": (_json_edit(lambda d: d.__setitem__("wall_s", float("inf"))), "wall_s"),
    "garbage line": (_garbage, "not valid JSON"),
    "truncated": (_truncated, "not valid JSON"),
    "no seed": (_json_edit(lambda d: d.__setitem__("per_seed", {})), "per_seed is empty"),
    "a key not a seed": (_json_edit(lambda d: d.__setitem__("per_seed", {"x": d["per_seed"].popitem()[1]})),
                         'per_seed: "x" is not a seed'),
}
CASES = [(name, kind) for name, kinds in DAMAGES.items() for kind in kinds]


@pytest.mark.parametrize("name, kind", CASES)
def test_a_damaged_run_file_is_one_line_naming_it_and_nothing_changes(capsys, killed_run, tmp_path, name, kind):
    run_dir = _copy(killed_run, tmp_path)
    damage, needle = DAMAGES[name][kind]
    damage(run_dir / name)
    before = hashes(run_dir)
    code, _, err = run(capsys, *RESUME, run_dir)
    one_line_error(code, err, needle)
    assert Path(name).name in err and hashes(run_dir) == before


@pytest.mark.parametrize("kind", list(DEMO_DAMAGES))
def test_a_damaged_metrics_json_is_one_line_naming_it_and_nothing_changes(capsys, demo_run, tmp_path, kind):
    out = tmp_path / "demo"
    shutil.copytree(demo_run, out)
    damage, needle = DEMO_DAMAGES[kind]
    damage(out / "run" / "metrics.json")
    before = hashes(out)
    code, _, err = run(capsys, "demo", "--steps", "160", "--envs", "8", "--episodes", "1", "--out", out)
    one_line_error(code, err, needle)
    assert "metrics.json" in err and hashes(out) == before


EVAL_DAMAGES = {
    "wrong type": (_json_edit(lambda d: d["levels"]["A"]["C_r"].__setitem__("value", [1])), "levels.A.C_r: value"),
    "missing field": (_json_edit(lambda d: d["levels"]["A"].pop("R_r")), "levels.A.R_r must be a JSON object"),
    "NaN": (_json_edit(lambda d: d["levels"]["A"]["avg_speed"].__setitem__("low", float("nan"))), "avg_speed: low"),
    "garbage line": (_garbage, "not valid JSON"),
    "truncated": (_truncated, "not valid JSON"),
    "per_seed not an object": (_json_edit(lambda d: d["levels"]["A"].__setitem__("per_seed", "x")),
                               "levels.A.per_seed must be a JSON object or null"),
    "a key not a seed": (_json_edit(lambda d: d["levels"]["A"].__setitem__("per_seed", {"x": dict(d["levels"]["A"])})),
                         'levels.A.per_seed: "x" is not a seed'),
    "trained_seeds": (_json_edit(lambda d: d.__setitem__("trained_seeds", ["x"])), "trained_seeds must be a JSON list"),
}


@pytest.fixture(scope="module")
def evaluation(tmp_path_factory, finished_run):
    out = tmp_path_factory.mktemp("eval") / "eval.json"
    assert main(["evaluate", str(finished_run), "--episodes", "1", "--json", "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize("kind", list(EVAL_DAMAGES))
def test_a_damaged_eval_json_is_one_line_naming_it_and_the_field(evaluation, tmp_path, kind):
    from highway_srl.experiments.records import read_eval

    path = tmp_path / "eval.json"
    shutil.copy(evaluation, path)
    read_eval(path)  # the file as evaluate writes it passes
    damage, needle = EVAL_DAMAGES[kind]
    damage(path)
    before = path.read_bytes()
    with pytest.raises(ValueError) as err:
        read_eval(path)
    assert needle in str(err.value) and str(path) in str(err.value) and "\n" not in str(err.value)
    assert path.read_bytes() == before


def test_drop_damaged_keeps_the_rows_before_a_damaged_line_and_says_how_many_it_dropped(capsys, killed_run, tmp_path):
    run_dir = _copy(killed_run, tmp_path)
    first = (run_dir / "episodes.jsonl").read_text().splitlines()[0]
    _garbage(run_dir / "episodes.jsonl")
    code, _, err = run(capsys, *RESUME, run_dir, "--drop-damaged")
    assert code == 0, err
    assert "dropped 3 row(s) from line 2 on, where it is damaged (not JSON" in err
    assert (run_dir / "episodes.jsonl").read_text().splitlines()[0] == first
    assert json.loads((run_dir / "metrics.json").read_text())["env_steps_per_seed"] == 1400


def test_a_cut_off_last_line_is_dropped_with_a_note(capsys, killed_run, tmp_path):
    run_dir = _copy(killed_run, tmp_path)
    kept = (run_dir / "episodes.jsonl").read_text().splitlines()[:2]  # the episodes before the checkpoint
    with open(run_dir / "episodes.jsonl", "a") as f:
        f.write('{"seed": 0, "step": 99')  # an append the kill cut short
    code, _, err = run(capsys, *RESUME, run_dir)
    assert code == 0 and "episodes.jsonl: dropped its cut-off last line (an interrupted write)" in err
    assert (run_dir / "episodes.jsonl").read_text().splitlines()[:2] == kept


# ---------------------------------------------------------------- never lose a file
RENDER = ("render", "--steps", "3", "--quiet", "--out")


def test_render_refuses_an_existing_gif_or_png_unless_overwrite(capsys, tmp_path):
    gif, png = tmp_path / "e.gif", tmp_path / "e.png"
    png.write_bytes(b"a PNG that was there")
    code, _, err = run(capsys, *RENDER, gif)
    one_line_error(code, err, "e.png exists; pass --overwrite")
    assert png.read_bytes() == b"a PNG that was there" and not gif.exists()
    code, _, err = run(capsys, *RENDER, gif, "--overwrite")
    assert code == 0, err
    assert gif.read_bytes()[:6] == b"GIF89a" and png.read_bytes()[:4] == b"\x89PNG"
    before = hashes(tmp_path)
    code, _, err = run(capsys, *RENDER, gif)
    one_line_error(code, err, "e.gif exists; pass --overwrite")
    assert hashes(tmp_path) == before


def test_a_drawing_that_fails_leaves_the_file_that_was_there(tmp_path):
    from highway_srl.experiments.renderings import drawn

    gif = tmp_path / "e.gif"
    gif.write_bytes(b"the good GIF")

    def full_disk(tmp: Path) -> None:
        tmp.write_bytes(b"GIF89a half")
        raise OSError(27, "File too large")

    with pytest.raises(OSError):
        drawn(gif, full_disk)
    assert gif.read_bytes() == b"the good GIF" and [p.name for p in tmp_path.iterdir()] == ["e.gif"]


def test_publish_without_replace_keeps_a_file_another_process_wrote_meanwhile(tmp_path):
    from highway_srl.agents.checkpoint import write_atomic

    path = tmp_path / "e.json"
    path.write_text("theirs")
    with pytest.raises(FileExistsError, match="written by another process meanwhile"):
        write_atomic(path, b"ours", replace=False)
    assert path.read_text() == "theirs" and [p.name for p in tmp_path.iterdir()] == ["e.json"]
    write_atomic(tmp_path / "new.json", b"ours", replace=False)
    assert (tmp_path / "new.json").read_text() == "ours"


@pytest.mark.parametrize("out", ["newdir/", "new/dir/"])
def test_evaluate_out_ending_in_a_slash_is_refused_as_a_folder(capsys, finished_run, tmp_path, out):
    code, _, err = run(capsys, "evaluate", finished_run, "--episodes", "1", "--out", str(tmp_path) + "/" + out)
    one_line_error(code, err, "is a folder; give a file name")
    assert not (tmp_path / "newdir").exists() and not (tmp_path / "new").exists()


HOLDER = """
import sys, time
from pathlib import Path
from highway_srl.experiments.runs import claim_outputs
with claim_outputs([Path(sys.argv[1])]):
    print("held", flush=True)
    time.sleep(120)
"""


def test_a_second_evaluate_onto_the_same_out_is_refused_while_the_first_writes(capsys, finished_run, tmp_path):
    """A real second process holds the output (as a running evaluate does): this one is refused at once."""
    out = tmp_path / "e.json"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdout=subprocess.PIPE, env=env, text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        code, _, err = run(capsys, "evaluate", finished_run, "--episodes", "1", "--out", out)
        one_line_error(code, err, "is being written by another process")
    finally:
        holder.kill()
        holder.wait()
    assert not out.exists()
    code, _, err = run(capsys, "evaluate", finished_run, "--episodes", "1", "--json", "--out", out)
    assert code == 0 and out.exists(), err  # the holder died: its lock went with it
    assert [p.name for p in tmp_path.iterdir()] == ["e.json"]


def test_demo_again_refuses_to_replace_its_report_unless_overwrite(capsys, demo_run, tmp_path):
    out = tmp_path / "demo"
    shutil.copytree(demo_run, out)
    (out / "report.md").write_text("the first demo's report")
    before = hashes(out)
    code, _, err = run(capsys, "demo", "--steps", "160", "--envs", "8", "--episodes", "2", "--out", out)
    one_line_error(code, err, "report.md exists; pass --overwrite")
    assert hashes(out) == before


def test_play_into_a_folder_holding_a_runs_episodes_is_refused(finished_run, tmp_path):
    from highway_srl.experiments.play import play

    folder = tmp_path / "p"
    folder.mkdir()
    shutil.copy(finished_run / "episodes.jsonl", folder)
    before = hashes(folder)
    with pytest.raises(ValueError, match="holds files but no run"):
        play("two-lane", "A", folder, wait_for_key=False)
    assert hashes(folder) == before


# ---------------------------------------------------------------- bounded work
@pytest.mark.parametrize("argv, needle", [
    (["evaluate", "RUN", "--episodes", "1e30"], "at most 2^53"),
    (["demo", "--episodes", "1e30"], "at most 2^53"),
    (["bench", "train", "--seeds", "1e30"], "at most 2^53"),
    (["render", "--seed", str(2**40)], "expected a seed from 0 to"),
    (["evaluate", "RUN", "--seed", str(2**64)], "at most 2^53"),
    (["train", "--seeds", f"0,{2**63}", "--out", "OUT"], "seeds must be distinct integers from 0 to"),
])
def test_absurd_numbers_are_one_line_before_any_work(capsys, finished_run, tmp_path, argv, needle):
    argv = [str(finished_run) if a == "RUN" else str(tmp_path / "o") if a == "OUT" else a for a in argv]
    code, _, err = run(capsys, *argv)
    one_line_error(code, err, needle)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, needle", [
    (["train", "--envs", "1000000", "--out", "OUT"], "training 1,000,000 envs"),
    (["bench", "train", "--seeds", "200", "--envs", "16"], "200 replay buffers"),
    (["evaluate", "RUN", "--episodes", "5e6", "--out", "OUT"], "use fewer --episodes"),
    (["demo", "--episodes", "5e6", "--out", "OUT"], "use fewer --episodes"),
])
def test_work_that_would_not_fit_in_memory_is_refused_before_it_starts(capsys, monkeypatch, finished_run, tmp_path,
                                                                      argv, needle):
    from highway_srl.experiments import bench

    monkeypatch.setattr(bench, "available_bytes", lambda device: 2**30)  # 1 GiB free, whatever the machine has
    argv = [str(finished_run) if a == "RUN" else str(tmp_path / "o") if a == "OUT" else a for a in argv]
    code, _, err = run(capsys, *argv)
    one_line_error(code, err, needle)
    assert "GiB" in err and list(tmp_path.iterdir()) == []


def test_the_training_estimate_lets_a_tiny_run_through():
    from highway_srl.experiments.bench import check_train_memory

    need = check_train_memory(TrainConfig(traffic="A", steps=400, envs=8, dqn=DQNConfig(buffer_capacity=2048)))
    assert 0 < need < 2**28
