"""Refactors change no behaviour: the simulator + rule layer trajectories and a short train + evaluate of
every method match the fingerprints in golden.json (see pin_data.py for what is hashed, why it runs in a
child process with fixed numeric settings, and how to update)."""

import json
import os
import subprocess
import sys

import pytest

from pin_data import GOLDEN, PIN_METHODS, PINNED_ENV, SCENARIOS, golden_for_host, host_key, method_key

GOLD = golden_for_host(json.loads(GOLDEN.read_text()))
# the last bits differ between CPU vendors (pin_data.py): a vendor without recorded pins cannot check them
pytestmark = pytest.mark.skipif(GOLD is None, reason=f"no pins recorded for this CPU vendor ({host_key()}); "
                                "record them with python tests/pins/pin_data.py --add-host at an unchanged commit")


def fingerprints(kind: str) -> dict:
    """Every fingerprint of one kind, computed by pin_data.py in a child process under PINNED_ENV."""
    script = os.path.join(os.path.dirname(__file__), "pin_data.py")
    done = subprocess.run([sys.executable, script, kind], env={**os.environ, **PINNED_ENV}, capture_output=True,
                          text=True)
    if done.returncode != 0:
        pytest.fail(f"pin_data.py {kind} failed: {done.stderr.strip().splitlines()[-1:]}")
    return json.loads(done.stdout)[kind]


@pytest.fixture(scope="module")
def trajectories():
    return fingerprints("trajectories")


@pytest.fixture(scope="module")
def methods():
    return fingerprints("methods")


def test_the_pins_cover_every_scenario_and_method():
    assert set(GOLD["trajectories"]) == {f"{s}/{a}" for s in SCENARIOS for a in ("nom", "adv")}
    assert set(GOLD["methods"]) == {method_key(m, o) for m, o in PIN_METHODS}


@pytest.mark.parametrize("scenario", SCENARIOS)
@pytest.mark.parametrize("adversarial", [False, True], ids=["nom", "adv"])
def test_trajectory_is_bit_identical_to_the_pinned_one(scenario, adversarial, trajectories):
    key = f"{scenario}/{'adv' if adversarial else 'nom'}"
    assert trajectories[key] == GOLD["trajectories"][key]


@pytest.mark.slow
@pytest.mark.parametrize("method,options", PIN_METHODS, ids=[method_key(m, o) for m, o in PIN_METHODS])
def test_short_train_and_evaluate_match_the_pinned_numbers(method, options, methods):
    key = method_key(method, options)
    assert methods[key] == GOLD["methods"][key]
