"""One intra-op thread per process by default (--threads, OMP_NUM_THREADS override), bench --contended and bench all."""

from __future__ import annotations

import json
import os

import pytest
import torch

from highway_srl.cli import main, set_threads


@pytest.fixture
def restore_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_one_thread_unless_asked(monkeypatch, restore_threads):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert set_threads(None) == 1 and torch.get_num_threads() == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    assert set_threads(None) == 2 and torch.get_num_threads() == 2
    assert set_threads(1) == 1 and torch.get_num_threads() == 1  # --threads wins over the environment
    monkeypatch.setenv("OMP_NUM_THREADS", "")  # unset-like values fall back to one
    assert set_threads(None) == 1
    set_threads(3)
    assert os.environ["OMP_NUM_THREADS"] == "3"  # what the worker processes of reproduce / bench take


def test_every_command_takes_threads(capsys, restore_threads):
    assert main(["bench", "sim", "--envs", "4", "--steps", "5", "--threads", "2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["envs"] == 4
    assert torch.get_num_threads() == 2
    assert main(["train", "--threads", "0"]) == 2  # a bad count is a usage error


def test_bench_contended_reports_idle_and_contended(capsys, restore_threads):
    assert main(["bench", "sim", "--envs", "4", "--steps", "5", "--contended", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["neighbours"] >= 1
    assert result["idle"]["env_steps_per_s"] > 0 and result["contended"]["env_steps_per_s"] > 0
    assert result["ratio"] == pytest.approx(result["contended"]["env_steps_per_s"] / result["idle"]["env_steps_per_s"])


def test_bench_all_prints_one_table_row_per_bench(capsys, monkeypatch, restore_threads):
    """bench all: the standard figures as docs/benchmarks.md's rows (what, figure, command, machine, commit)."""
    import highway_srl.cli as cli

    monkeypatch.setattr(cli, "ALL_BENCHES", (("tiny sim", ["sim", "--envs", "4", "--steps", "5"]),
                                             ("tiny train", ["train", "--envs", "2", "--steps", "3"])))
    assert main(["bench", "all"]) == 0
    rows = capsys.readouterr().out.strip().splitlines()
    assert [r.split(" | ")[0] for r in rows] == ["| tiny sim", "| tiny train"]
    assert all(r.count(" | ") == 4 and r.endswith(" |") for r in rows)
    assert "`highway-srl bench sim --envs 4 --steps 5`" in rows[0] and "env-steps/s" in rows[1]
    assert main(["bench", "all", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["row"], r["what"]) for r in rows] == [("tiny sim", "sim"), ("tiny train", "train")]
    assert main(["bench", "all", "--contended"]) == 2
