import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))  # cli_runs (the CLI tests' helpers) importable by name

from cli_runs import TRAIN  # noqa: E402

from highway_srl.cli import main  # noqa: E402


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "run"
    assert main(TRAIN + ["--steps", "160", "--out", str(out)]) == 0
    return out
