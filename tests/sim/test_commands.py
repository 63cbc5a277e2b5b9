"""World.step refuses commands it cannot honour (a lane off the road, a float lane, a wrong count, a speed that
is not finite or negative) with one ValueError, before anything moves."""

import math

import numpy as np
import pytest
import torch

from highway_srl.sim import World


def _state(world: World) -> list[torch.Tensor]:
    s = world.state
    return [t.clone() for t in (s.x, s.y, s.v, s.t, s.lane, s.target_lane)]


@pytest.mark.parametrize("lane, speed, message", [
    (7, 8.0, "target_lane must be a lane of this road, 0..1, or -1 (hold the lateral position), got 7..7"),
    ([-2, 0, 1], [8.0] * 3, "target_lane must be a lane of this road, 0..1, or -1 (hold the lateral position), got -2..1"),
    (torch.tensor([1.0, 0.0, 1.0]), [8.0] * 3, "target_lane must hold integer lane indices, got dtype torch.float32"),
    (np.array([True, False, True]), [8.0] * 3, "got dtype torch.bool"),
    ([0, 1], [8.0] * 3, "target_lane needs 3 value(s), one per env, got shape (2,)"),
    ([0, 1, 1], [8.0] * 4, "target_speed needs 3 value(s), one per env, got shape (4,)"),
    ([0, 1, 1], [8.0, math.nan, 8.0], "target_speed must be finite and >= 0 m/s, got nan..nan"),
    ([0, 1, 1], [8.0, math.inf, 8.0], "got 8.0..inf"),
    ([0, 1, 1], [8.0, -2.0, 8.0], "got -2.0..8.0"),
])
def test_bad_commands_are_one_value_error_and_nothing_moves(lane, speed, message):
    world = World("two-lane", "C", num_envs=3, seed=1)
    if np.ndim(lane) == 0:
        lane, speed = [lane] * 3, [speed] * 3
    before = _state(world)
    for step in (world.step, world.step_and_reset):
        with pytest.raises(ValueError) as info:
            step(lane, speed)
        assert message in str(info.value), str(info.value)
    assert all(torch.equal(a, b) for a, b in zip(before, _state(world)))


def test_the_ramp_lane_is_a_lane_of_a_ramp_road():
    world = World("merge", "C", num_envs=1, seed=0)
    world.step([2], [8.0])  # merge: lane 2 is the on-ramp
    with pytest.raises(ValueError, match=r"0..2, or -1 \(hold the lateral position\), got 3..3"):
        world.step([3], [8.0])


def test_valid_commands_in_every_accepted_form_step_alike():
    """Python numbers, lists, NumPy arrays of any integer / float type and tensors are one command; a speed above
    v_max is valid (the ego's controller clamps it)."""
    forms = [([1, 0], [8.0, 25.0]), (np.array([1, 0], dtype=np.int32), np.array([8.0, 25.0])),
             (torch.tensor([1, 0]), torch.tensor([8.0, 25.0], dtype=torch.float64))]
    results = []
    for lane, speed in forms:
        world = World("two-lane", "C", num_envs=2, seed=4)
        for _ in range(5):
            world.step(lane, speed)
        results.append(_state(world))
    assert all(torch.equal(a, b) for r in results[1:] for a, b in zip(results[0], r))


def test_check_commands_false_skips_the_value_read():
    """The opt-out, for callers that guarantee their commands: the values are not read, so a NaN speed goes
    through (and makes the ego's speed NaN); the default refuses it."""
    world = World("two-lane", "C", num_envs=1, seed=0)
    world.check_commands = False
    world.step([1], [math.nan])
    assert math.isnan(world.ego_speed[0].item())
    with pytest.raises(ValueError, match="finite"):
        World("two-lane", "C", num_envs=1, seed=0).step([1], [math.nan])


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device; none is available here")
def test_commands_on_a_cuda_device_are_read_only_when_asked():
    """Reading a CUDA tensor waits for the device, so by default only its dtype and count are checked; with
    check_commands = True its values are too. Host commands to a CUDA world are checked before the copy."""
    world = World("two-lane", "C", num_envs=2, device="cuda", seed=0)
    nan = torch.tensor([8.0, math.nan], device="cuda")
    world.step(torch.tensor([0, 1], device="cuda"), nan)  # not read
    with pytest.raises(ValueError, match="finite"):
        world.step([0, 1], [8.0, math.nan])  # host values: checked
    world.check_commands = True
    with pytest.raises(ValueError, match="finite"):
        world.step(torch.tensor([0, 1], device="cuda"), nan)
    with pytest.raises(ValueError, match="integer lane indices"):
        world.step(torch.tensor([0.0, 1.0], device="cuda"), [8.0, 8.0])
