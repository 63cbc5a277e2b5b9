"""Helpers of the CLI tests: a small training command, a folder's hashes, a command's exit status and output."""

import hashlib
from pathlib import Path

from highway_srl.cli import main
from highway_srl.experiments import train as train_mod

TRAIN = ["train", "--traffic", "A", "--envs", "8", "--learning-starts", "64", "--quiet"]


def hashes(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err, needle):
    assert code == 2, err
    assert needle in err, err
    assert err.count("\n") == 1 and "Traceback" not in err, err


def interrupted_run(tmp_path, monkeypatch, capsys, steps=400, every=80, die_after=25):
    """A run killed by Ctrl-C after `die_after` vector steps (8 envs): resume/ holds its checkpoint."""
    real_step, calls = train_mod.Trainer.step, {"n": 0}

    def dying(self):
        calls["n"] += 1
        if calls["n"] > die_after:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(train_mod.Trainer, "step", dying)
    out = tmp_path / "killed"
    code, _, err = run(capsys, *TRAIN, "--steps", steps, "--checkpoint-every", every, "--out", out)
    monkeypatch.setattr(train_mod.Trainer, "step", real_step)
    return out, code, err
