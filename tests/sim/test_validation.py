"""Bad arguments fail early with a ValueError that names the bad value and the allowed ones."""

from __future__ import annotations

import pytest
import torch

from highway_srl.sim import World, make_road


@pytest.mark.parametrize(
    "kwargs, bad, allowed",
    [
        ({"scenario": "roundabout"}, "'roundabout'", "two-lane"),
        ({"traffic": "G"}, "'G'", "A, B, C, D, E, F"),
        ({"traffic": "c"}, "'c'", "A, B, C, D, E, F"),
        ({"style": "reckless"}, "'reckless'", "aggressive, normal, cautious"),
        ({"num_envs": 0}, "0", "positive integer"),
        ({"num_envs": -3}, "-3", "positive integer"),
        ({"num_envs": 2.5}, "2.5", "positive integer"),
        ({"num_vehicles": 64}, "64", "between 1 and 63"),
        ({"num_vehicles": 0}, "0", "between 1 and 63"),
        ({"max_steps": 0}, "0", "positive integer"),
        ({"device": "tpu"}, "'tpu'", "cpu, cuda"),
        ({"device": "banana"}, "'banana'", "cpu, cuda"),
        ({"num_envs": 3, "seed": [1, 2]}, "2", "3 seeds"),
    ],
)
def test_bad_world_arguments_raise_value_errors_naming_value_and_choices(kwargs, bad, allowed):
    with pytest.raises(ValueError) as info:
        World(**kwargs)
    message = str(info.value)
    assert bad in message and allowed in message, message


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is available here, so 'cuda' is a valid device")
def test_cuda_without_a_gpu_is_a_value_error_that_suggests_cpu():
    with pytest.raises(ValueError) as info:
        World(device="cuda")
    assert "'cuda'" in str(info.value) and "cpu" in str(info.value)


def test_unknown_scenario_for_make_road_lists_the_scenarios():
    with pytest.raises(ValueError, match=r"'ramp'.*two-lane, multi-lane, merge, exit"):
        make_road("ramp")
