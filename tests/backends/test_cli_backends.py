"""The same trained agent evaluated and rendered on simulators we did not write, through the CLI."""

import json

import pytest

from highway_srl.cli import main


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("backend-runs") / "run"
    assert main(["train", "--scenario", "merge", "--traffic", "A", "--steps", "160", "--envs", "8",
                 "--learning-starts", "64", "--quiet", "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize("backend, module", [("sumo", "libsumo"), ("highway-env", "highway_env")])
def test_evaluate_and_render_on_other_backends(backend, module, trained_run, tmp_path, capsys):
    pytest.importorskip(module, reason=f"the {backend} extra is not installed (pip install 'highway-srl[{backend}]')")
    out = tmp_path / f"{backend}.json"
    assert main(["evaluate", str(trained_run), "--backend", backend, "--episodes", "1", "--out", str(out)]) == 0
    level = json.loads(out.read_text())["levels"]["A"]
    assert level["episodes"] == 1 and 0.0 <= level["R_s"]["value"] <= 1.0
    gif = tmp_path / f"{backend}.gif"
    assert main(["render", str(trained_run), "--backend", backend, "--steps", "16", "--out", str(gif)]) == 0
    assert gif.stat().st_size > 1000
    capsys.readouterr()
