"""Issue 15: nothing the user had is lost, nothing is silently wrong. Each bad case gives the right answer or
one line on stderr with exit status 2, and every file that was there is unchanged (hashes before/after)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

from cli_runs import TRAIN, hashes, interrupted_run, one_line_error, run

from highway_srl.cli import build_parser, main
from highway_srl.experiments import train as train_mod

ROOT = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------- data loss / silently wrong answers
def test_resume_of_a_finished_run_says_so_and_changes_nothing(capsys, finished_run):
    before = hashes(finished_run)
    code, out, _ = run(capsys, "train", "--resume", "--out", finished_run)
    assert code == 0 and "already finished" in out
    assert hashes(finished_run) == before


def test_traffic_ranges_and_lists_give_the_right_levels():
    from highway_srl.commands import levels

    assert levels("A..F") == levels("F..A") == list("ABCDEF")
    assert levels("c") == ["C"] and levels("f,a, c") == ["A", "C", "F"] and levels("E-B") == list("BCDE")


@pytest.mark.parametrize("text", ["", ",,", "C,,F", "F..Z", "G"])
def test_empty_or_unknown_traffic_is_an_error_not_level_c(capsys, finished_run, tmp_path, text):
    code, _, err = run(capsys, "evaluate", finished_run, "--traffic", text, "--out", tmp_path / "e.json")
    one_line_error(code, err, "--traffic")
    assert not (tmp_path / "e.json").exists()


@pytest.mark.parametrize("command", [["train", "--out", "x"], ["render"], ["bench", "sim"]])
def test_lower_case_traffic_level_is_accepted_by_every_command(command):
    assert build_parser().parse_args(command + ["--traffic", "c"]).traffic == "C"


def test_two_trainings_on_one_folder_at_once_one_is_refused(tmp_path):
    out = tmp_path / "both"
    cmd = [sys.executable, "-m", "highway_srl.cli", *TRAIN, "--steps", "800", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    procs = [subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    codes = sorted(code for code, _ in results)
    assert codes == [0, 2], results
    refused = next(err for code, err in results if code == 2)
    assert ("in use by another process" in refused or "already holds a run" in refused) and "Traceback" not in refused
    episodes = (out / "episodes.jsonl").read_text().splitlines()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["per_seed"]["0"]["episodes"] == len(episodes)
    steps = [int(line.split(",")[0]) for line in (out / "scalars.csv").read_text().splitlines()[1:]]
    assert steps == sorted(set(steps))  # no row twice


def test_a_locked_run_folder_is_refused_and_a_killed_holder_does_not_block(capsys, tmp_path, monkeypatch):
    out, code, _ = interrupted_run(tmp_path, monkeypatch, capsys)
    assert code == 130
    holder = subprocess.Popen([sys.executable, "-c", (
        "import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT); "
        "fcntl.flock(fd, fcntl.LOCK_EX); os.write(fd, str(os.getpid()).encode()); print('locked', flush=True); "
        "time.sleep(600)"), str(out / ".lock")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        before = hashes(out)
        code, _, err = run(capsys, "train", "--resume", "--out", out)
        one_line_error(code, err, "in use by another process")
        assert hashes(out) == before
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert run(capsys, "train", "--resume", "--quiet", "--out", out)[0] == 0  # the stale lock file is no obstacle
    assert (out / "metrics.json").exists() and not (out / "resume").exists()


def test_interrupt_says_how_to_resume_and_resume_keeps_checkpoint_every(capsys, tmp_path, monkeypatch):
    out, code, err = interrupted_run(tmp_path, monkeypatch, capsys, steps=480, every=80, die_after=25)
    assert code == 130
    assert err.strip().splitlines()[-1] == (
        f"highway-srl: interrupted; continue from its last checkpoint (step 160) with: "
        f"highway-srl train --resume --out {out}")
    assert json.loads((out / "config.json").read_text())["checkpoint_every"] == 80
    saved = []
    real_save = train_mod.save_checkpoint

    def record(path, tensors, meta):
        saved.append((Path(path).name, meta["env_steps"]))
        return real_save(path, tensors, meta)

    monkeypatch.setattr(train_mod, "save_checkpoint", record)
    assert run(capsys, "train", "--resume", "--quiet", "--out", out)[0] == 0
    assert saved == [("resume", 240), ("resume", 320), ("resume", 400), ("model", 480)]


def test_train_into_a_folder_that_holds_other_files_is_refused(capsys, tmp_path):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "metrics.json").write_text("my own results\n")
    before = hashes(folder)
    code, _, err = run(capsys, *TRAIN, "--steps", "64", "--out", folder)
    one_line_error(code, err, "holds files but no run")
    assert hashes(folder) == before and sorted(os.listdir(folder)) == ["metrics.json"]


def test_demo_does_not_reuse_a_run_with_other_settings(capsys, tmp_path):
    out = tmp_path / "out"
    (out / "run").mkdir(parents=True)
    config = {"method": "moe-rm-srl", "scenario": "two-lane", "traffic": "C", "steps": 30000, "envs": 16, "seeds": [0]}
    (out / "run" / "config.json").write_text(json.dumps({"config": config}))
    (out / "run" / "metrics.json").write_text("{}")
    before = hashes(out)
    code, _, err = run(capsys, "demo", "--out", out, "--steps", "1000")
    one_line_error(code, err, "--steps 30000")
    assert hashes(out) == before


def test_demo_into_a_folder_that_holds_other_files_is_refused(capsys, tmp_path):
    (tmp_path / "notes.txt").write_text("keep me")
    code, _, err = run(capsys, "demo", "--out", tmp_path, "--steps", "100")
    one_line_error(code, err, "holds files but no demo run")
    assert os.listdir(tmp_path) == ["notes.txt"]


def test_evaluate_never_replaces_a_result_without_overwrite(capsys, finished_run, tmp_path):
    out = tmp_path / "eval.json"
    assert run(capsys, "evaluate", finished_run, "--episodes", "2", "--out", out)[0] == 0
    before = hashes(tmp_path)
    code, _, err = run(capsys, "evaluate", finished_run, "--episodes", "3", "--out", out)
    one_line_error(code, err, "--overwrite")
    assert hashes(tmp_path) == before
    assert run(capsys, "evaluate", finished_run, "--episodes", "3", "--out", out, "--overwrite")[0] == 0
    assert json.loads(out.read_text())["episodes_per_level"] == 3


def test_evaluate_checks_its_output_before_evaluating(capsys, finished_run, tmp_path, monkeypatch):
    from highway_srl.experiments import evaluate

    monkeypatch.setattr(evaluate, "evaluate_run", lambda *a, **k: pytest.fail("evaluated before checking --out"))
    (tmp_path / "afile").write_text("x")
    for out, needle in ((tmp_path, "is a folder"), (tmp_path / "afile" / "e.json", "is a file")):
        code, _, err = run(capsys, "evaluate", finished_run, "--out", out)
        one_line_error(code, err, needle)


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600)])
def test_written_files_get_the_usual_mode_under_the_umask(tmp_path, umask, mode):
    from highway_srl.agents.checkpoint import save_checkpoint
    from highway_srl.experiments.runs import write_json, write_jsonl

    old = os.umask(umask)
    try:
        write_json(tmp_path / "a.json", {"x": 1})
        save_checkpoint(tmp_path / "model", {"w": torch.zeros(2)}, {"m": 1})
        write_jsonl(tmp_path / "e.jsonl", [{"step": 1}])
    finally:
        os.umask(old)
    for path in (tmp_path / "a.json", tmp_path / "model" / "model.safetensors", tmp_path / "model" / "meta.json",
                 tmp_path / "e.jsonl"):
        assert path.stat().st_mode & 0o777 == mode, path


def test_a_training_run_is_readable_by_colleagues(finished_run):
    mask = os.umask(0o022)
    os.umask(mask)
    if mask & 0o044:  # the suite's own umask decides; 022 is the usual one
        pytest.skip("the umask hides files from group and others")
    for name in ("config.json", "metrics.json", "model/model.safetensors", "model/meta.json", "episodes.jsonl"):
        assert (finished_run / name).stat().st_mode & 0o044 == 0o044, name


# ---------------------------------------------------------------- one line instead of a traceback
@pytest.mark.parametrize("content", ["{}", "[]", '{"config": null}', '{"config": {}}', "not json"])
@pytest.mark.parametrize("command", ["evaluate", "render", "resume"])
def test_damaged_config_is_one_line(capsys, finished_run, tmp_path, content, command):
    import shutil

    run_dir = tmp_path / "r"
    shutil.copytree(finished_run, run_dir)
    (run_dir / "metrics.json").unlink()  # so that --resume does not stop at "finished"
    (run_dir / "config.json").write_text(content)
    before = hashes(run_dir)
    argv = {"evaluate": ["evaluate", run_dir, "--out", tmp_path / "e.json"],
            "render": ["render", run_dir, "--out", tmp_path / "e.gif"],
            "resume": ["train", "--resume", "--out", run_dir]}[command]
    code, _, err = run(capsys, *argv)
    one_line_error(code, err, "config.json")
    assert hashes(run_dir) == before


@pytest.mark.parametrize("device", ["tpu"] + ([] if torch.cuda.is_available() else ["cuda"]))
def test_evaluate_on_a_missing_device_is_one_line(capsys, finished_run, tmp_path, device):
    code, _, err = run(capsys, "evaluate", finished_run, "--device", device, "--out", tmp_path / "e.json")
    one_line_error(code, err, repr(device))


def test_paths_through_a_file_are_one_line(capsys, tmp_path, finished_run):
    (tmp_path / "somefile").write_text("x")
    code, _, err = run(capsys, *TRAIN, "--steps", "64", "--out", tmp_path / "somefile" / "sub")
    one_line_error(code, err, "is a file, not a folder")
    code, _, err = run(capsys, "evaluate", tmp_path / "somefile")
    one_line_error(code, err, "is a file, not a run folder")
    assert (tmp_path / "somefile").read_text() == "x"


def _edit_resume(folder: Path, edit) -> None:
    path = folder / "resume" / "model.safetensors"
    tensors = load_file(path)
    edit(tensors)
    save_file(tensors, path)


@pytest.mark.parametrize("damage, needle", [
    (lambda t: t.pop("learner.q.0.weight", None) or t.pop(next(k for k in t if k.startswith("learner."))), "lacks"),
    (lambda t: t.__setitem__("world.x", t["world.x"][:, :-1].contiguous()), "world.x"),
    (lambda t: t.__setitem__("rng.trainer", t["rng.trainer"][:100].contiguous()), "rng.trainer"),
    (lambda t: t.__setitem__("replay.obs", t["replay.obs"][:-3].contiguous()), "replay.obs"),
    (lambda t: t.pop("replay.size"), "replay"),
])
def test_damaged_resume_checkpoint_is_one_line_and_folder_unchanged(capsys, tmp_path, monkeypatch, damage, needle):
    out, code, _ = interrupted_run(tmp_path, monkeypatch, capsys)
    assert code == 130 and (out / "resume").exists()
    _edit_resume(out, damage)
    before = hashes(out)
    code, _, err = run(capsys, "train", "--resume", "--quiet", "--out", out)
    one_line_error(code, err, needle)
    assert hashes(out) == before


def test_resume_with_a_checkpoint_of_other_envs_is_one_line(capsys, tmp_path, monkeypatch):
    out, _, _ = interrupted_run(tmp_path, monkeypatch, capsys)
    config = json.loads((out / "config.json").read_text())
    config["config"]["envs"] = 4
    (out / "config.json").write_text(json.dumps(config))
    before = hashes(out)
    code, _, err = run(capsys, "train", "--resume", "--quiet", "--out", out)
    one_line_error(code, err, "envs 4")
    assert hashes(out) == before


def test_bench_sim_refuses_more_envs_than_memory_before_allocating(capsys):
    code, _, err = run(capsys, "bench", "sim", "--envs", "1000000000", "--steps", "2")
    one_line_error(code, err, "available")
    assert "GiB" in err and "1,000,000,000 envs" in err


@pytest.mark.parametrize("argv, needle", [
    (TRAIN + ["--learning-starts", "-5", "--out", "x"], "--learning-starts"),
    (TRAIN + ["--replay-ratio", "-1", "--out", "x"], "--replay-ratio"),
    (TRAIN + ["--profile", "careful", "--out", "x"], "unknown profile 'careful'"),
    (TRAIN + ["--adversary", "evil", "--out", "x"], "unknown adversary 'evil'"),
    (TRAIN + ["--steps", "5.5", "--out", "x"], "--steps"),
    (["render", "--seed", "-1"], "--seed"),
    (["play", "--fps", "-1", "--out", "x"], "--fps"),
    (["play", "--fps", "0", "--out", "x"], "--fps"),
    (["evaluate", "x", "--episodes", "0"], "--episodes"),
    (["train"], "--out"),
    (["nonsense"], "invalid choice"),
])
def test_meaningless_numbers_and_usage_errors_are_one_line(capsys, tmp_path, monkeypatch, argv, needle):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, *argv)
    one_line_error(code, err, needle)
    assert "usage:" not in err and os.listdir(tmp_path) == []


def test_steps_in_the_papers_notation_are_accepted():
    args = build_parser().parse_args(["train", "--steps", "5e5", "--out", "x"])
    assert args.steps == 500_000 and isinstance(args.steps, int)


def test_play_without_a_display_refuses_at_once(capsys, tmp_path, monkeypatch):
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    code, _, err = run(capsys, "play", "--out", tmp_path / "manual")
    one_line_error(code, err, "needs a display")
    assert not (tmp_path / "manual").exists()


# ---------------------------------------------------------------- what a researcher reads
def test_progress_bar_ends_at_its_total_and_interrupt_message_has_its_own_line(capsys, tmp_path):
    code, _, err = run(capsys, "train", "--traffic", "A", "--envs", "8", "--steps", "50", "--learning-starts", "8",
                       "--out", tmp_path / "r")
    assert code == 0
    assert "50/50" in err and "56/50" not in err  # 7 vector steps of 8 envs: the bar stops at its total


def test_a_run_too_short_to_learn_says_so_and_still_runs(capsys, tmp_path):
    code, out, err = run(capsys, "train", "--traffic", "A", "--envs", "8", "--steps", "40", "--quiet",
                         "--out", tmp_path / "r")  # the default learning start is 1,000 env steps
    assert code == 0 and "note: learning starts after 1,000 env steps, more than --steps 40" in err
    assert "rise time" in out and "None" not in out  # no rise within 5 vector steps: "n/a", not None
    code, _, err = run(capsys, "train", "--method", "rule-based", "--traffic", "A", "--envs", "8", "--steps", "40",
                       "--quiet", "--out", tmp_path / "rb")
    assert code == 0 and "note:" not in err  # nothing to learn, nothing to say


def test_deployment_figure_keeps_rates_within_100_percent_with_intervals():
    from highway_srl.experiments.demo import deployment_figure, deployment_table

    stat = lambda v, lo, hi: {"value": v, "low": lo, "high": hi}  # noqa: E731
    report = {"levels": {"A": {"C_r": stat(1.0, 0.93, 1.0), "avg_speed": stat(8.0, 7.5, 8.5), "R_r": stat(90, 80, 100)},
                         "F": {"C_r": stat(0.5, 0.36, 0.64), "avg_speed": stat(6.0, 5.5, 6.5), "R_r": stat(40, 30, 50),
                               "collisions": {"collisions": 3, "by_kind": {"front": 2, "side": 1}}}}}
    plt, fig = deployment_figure(report)
    ax = fig.axes[0]
    assert ax.get_ylim()[1] <= 100.0 and len(ax.containers) == 2  # one errorbar per level
    plt.close(fig)
    table = deployment_table(report)
    assert "| A | 100.0% [93.0%, 100.0%] | 8.00 [7.50, 8.50] | 90.0 [80.0, 100.0] | none |" in table
    assert "| F | 50.0% [36.0%, 64.0%] | 6.00 [5.50, 6.50] | 40.0 [30.0, 50.0] | 2 front, 1 side |" in table


def test_render_names_the_styles_and_the_reward_machine_state():
    from highway_srl.experiments.policy import rm_label
    from highway_srl.sim import World
    from highway_srl.sim.render import capture, frame_figure

    world = World("two-lane", "C", num_envs=1, seed=0)
    plt, fig, ax = frame_figure(world.road, capture(world, text=["Faster by expert", rm_label(0)]))
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["ego", "aggressive driver", "normal driver", "cautious driver"]
    assert "RM state u1: in lane" in ax.get_title(loc="left")
    assert all(t.get_fontsize() >= 9 for t in ax.texts + ax.get_legend().get_texts())  # no 7 pt labels
    width, height = fig.get_size_inches()
    assert height < 0.3 * width  # cropped to the road, not a tall empty canvas
    plt.close(fig)


def test_resume_checkpoint_holds_only_the_filled_part_of_the_replay(capsys, tmp_path, monkeypatch):
    out, _, _ = interrupted_run(tmp_path, monkeypatch, capsys)
    tensors = load_file(out / "resume" / "model.safetensors")
    filled = int(tensors["replay.size"].sum())
    assert tensors["replay.obs"].shape[0] == filled + 1  # + the scratch row
    assert filled <= 160 * 8  # at most one row per transition so far
