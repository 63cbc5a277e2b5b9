"""A full disk (here a file size limit, RLIMIT_FSIZE, which fails a write() with EFBIG as ENOSPC would) is one
line naming the file, exit status 1 (the machine, not the command line: usage errors are 2), no traceback,
no temporary file left, and every file that was there before unchanged."""

import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

from cli_runs import TRAIN, hashes, interrupted_run

ROOT = Path(__file__).resolve().parents[2]


def limited(limit: int, *argv) -> tuple[int, str]:
    """The CLI with argv in a child process that may write no file beyond `limit` bytes."""
    def cap():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write over the limit fails instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "highway_srl.cli", *map(str, argv)], env=env, preexec_fn=cap,
                          capture_output=True, text=True, timeout=600)
    return proc.returncode, proc.stderr


def full_disk(code: int, err: str, path: Path) -> None:
    assert code == 1, err
    assert err == f"highway-srl: error: {path}: File too large\n", err


def no_temporary_files(folder: Path) -> None:
    assert not [p for p in folder.rglob("*") if ".tmp" in p.name or p.name.endswith(".lock.tmp")]


def test_training_that_cannot_write_its_model_names_the_file(tmp_path):
    out = tmp_path / "run"
    code, err = limited(50_000, *TRAIN, "--steps", 160, "--out", out)
    full_disk(code, err, out / "model" / "model.safetensors")
    no_temporary_files(out)


def test_training_that_cannot_write_its_tensorboard_events_names_the_folder(tmp_path):
    out = tmp_path / "run"
    code, err = limited(1_500, *TRAIN, "--steps", 4000, "--out", out)
    assert code == 1, err
    assert err.startswith(f"highway-srl: error: {out / 'tb'}") and err.endswith(": File too large\n"), err
    assert err.count("\n") == 1 and "Traceback" not in err
    no_temporary_files(out)


def test_a_checkpoint_that_cannot_be_written_keeps_the_one_before(tmp_path, monkeypatch, capsys):
    out, code, _ = interrupted_run(tmp_path, monkeypatch, capsys)
    assert code == 130
    before = hashes(out / "resume")
    biggest = max(p.stat().st_size for p in (out / "resume").rglob("*") if p.is_file())
    logs = max((out / name).stat().st_size for name in ("episodes.jsonl", "scalars.csv"))
    code, err = limited(max(logs * 4, 20_000), "train", "--resume", "--quiet", "--out", out)
    assert code == 1 and err.startswith(f"highway-srl: error: {out / 'resume'}"), err
    assert err.endswith(": File too large\n") and err.count("\n") == 1, err
    assert hashes(out / "resume") == before and biggest > max(logs * 4, 20_000)
    no_temporary_files(out)


def test_render_that_cannot_write_keeps_the_gif_it_would_replace(tmp_path):
    gif, png = tmp_path / "x.gif", tmp_path / "x.png"
    gif.write_text("the old GIF")
    png.write_text("the old PNG")
    code, err = limited(2_000, "render", "--steps", 5, "--quiet", "--overwrite", "--out", gif)
    assert code == 1 and err in (f"highway-srl: error: {gif}: File too large\n",
                                 f"highway-srl: error: {png}: File too large\n"), err
    assert gif.read_text() == "the old GIF" and png.read_text() == "the old PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.gif", "x.png"]
