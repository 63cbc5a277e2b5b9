"""What a world step reports: its events (StepEvents) and the task's latched stages (StageFlags)."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class StepEvents:
    """What happened in one step, per env (B,) bool unless noted."""

    collision: torch.Tensor  # the ego hit a vehicle, a lane end or left the road
    success: torch.Tensor  # exit: reached the off-ramp's end (terminal); merge: reached the stability zone
    failure: torch.Tensor  # exit: missed the off-ramp (terminal)
    terminated: torch.Tensor
    truncated: torch.Tensor  # the 320-step limit
    sv_collisions: torch.Tensor  # (B,) long, SV-SV pairs whose boxes overlap after this step (nominal traffic: 0)


# StepEvents' fields and dtypes, for those that allocate them before a step (the worker processes' buffers)
STEP_EVENT_DTYPES = {"collision": torch.bool, "success": torch.bool, "failure": torch.bool, "terminated": torch.bool,
                     "truncated": torch.bool, "sv_collisions": torch.long}


@dataclass
class StageFlags:
    """The task's latched stages of the current episodes, (B,) bool each (§4.3's r_merge, r_exit,1, r_exit,2;
    the names a ScenarioSpec's reward terms and success_flag use)."""

    merged: torch.Tensor  # merge: the ego has reached the stability zone in a mainline lane
    exit1: torch.Tensor  # exit: it has entered lane 1, next to the off-ramp
    exit2: torch.Tensor  # exit: it has entered the off-ramp lane 2

    def reward_inputs(self) -> dict[str, torch.Tensor]:
        """The flags under the rewards' keyword names (r_merge, r_exit1, r_exit2), for scenario_reward and
        deployment_step_reward."""
        return {"r_merge": self.merged, "r_exit1": self.exit1, "r_exit2": self.exit2}
