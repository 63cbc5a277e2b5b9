"""Refactors change no behaviour: the simulator + rule layer trajectories and a short train + evaluate of
every method match the fingerprints in golden.json (see pin_data.py for what is hashed and how to update)."""

import json

import pytest

from pin_data import GOLDEN, PIN_METHODS, SCENARIOS, method_fingerprint, trajectory_hash

GOLD = json.loads(GOLDEN.read_text())


@pytest.mark.parametrize("scenario", SCENARIOS)
@pytest.mark.parametrize("adversarial", [False, True], ids=["nom", "adv"])
def test_trajectory_is_bit_identical_to_the_pinned_one(scenario, adversarial):
    key = f"{scenario}/{'adv' if adversarial else 'nom'}"
    assert trajectory_hash(scenario, adversarial) == GOLD["trajectories"][key]


@pytest.mark.slow
@pytest.mark.parametrize("method,options", PIN_METHODS, ids=[m + "".join(f"+{k}" for k in o) for m, o in PIN_METHODS])
def test_short_train_and_evaluate_match_the_pinned_numbers(method, options, tmp_path):
    key = method + "".join(f"+{k}" for k in sorted(options))
    assert method_fingerprint(method, options, tmp_path) == GOLD["methods"][key]
