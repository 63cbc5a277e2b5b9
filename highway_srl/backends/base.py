"""What the one-env foreign-simulator backends (SUMO, highway-env) share: the constructor (the common
arguments, their checks, the episode core, then the `_open` hook and the first episode), reset, and the
skeleton of a step. A backend specialises it with its own arguments and its hooks (start, command, read).

A step: accept the commanded ego lane as World does and command the ego; start the adversarial cut-ins
that fired; advance the foreign simulator and read its frame and collisions (`_simulate`); release the
cut-in SVs that arrived; move the SVs that recycling moves; then the episode core's events.
"""

from __future__ import annotations

import torch

from highway_srl.backends.bookkeeping import EpisodeCore, Frame, FrameQueries, Move
from highway_srl.constants import EPISODE_STEPS, V_MAX_MPS
from highway_srl.sim.events import StepEvents


class SingleEnvBackend(FrameQueries):
    """One episode of a scenario in a foreign simulator behind the Backend protocol (num_envs = 1, CPU)."""

    num_envs = 1
    _ego_gone = False  # the simulator removed the ego (SUMO: the end of its route); the episode is truncated

    def __init__(self, scenario: str = "two-lane", traffic: str = "C", adversarial: bool = False, seed: int = 0,
                 style: str | None = None, num_vehicles: int | None = None, max_steps: int = EPISODE_STEPS) -> None:
        """The episode core and the protocol's attributes (validates the shared arguments), then the
        simulator (`_open`) and the first episode. A backend checks its own arguments before calling this."""
        self._core = EpisodeCore(scenario, traffic, adversarial, seed, style, num_vehicles, max_steps)
        self.scenario, self.traffic, self.adversarial = scenario, traffic, bool(adversarial)
        self.road, self.max_steps = self._core.road, max_steps
        self.device = torch.device("cpu")
        self._frame = Frame.empty(self._core.num_vehicles)
        self._open()
        self._spawn_episode()

    # ------------------------------------------------------------------ hooks
    def _open(self) -> None:
        """Start the simulator for self.road (the core exists); called once, by the constructor."""
        raise NotImplementedError

    def _check_open(self) -> None:
        """Raise if the simulator is gone (closed); nothing by default."""

    def _spawn_episode(self) -> None:
        """Put the core's initial scene into the simulator and read the first frame."""
        raise NotImplementedError

    def _command_ego(self, target: int, speed: float) -> None:
        """Command the ego: the accepted target lane and a speed in [0, v_max] m/s."""
        raise NotImplementedError

    def _cut_in(self, j: int, lane: int) -> None:
        """Start SV j's forced cut-in into our lane `lane`."""
        raise NotImplementedError

    def _simulate(self) -> tuple[bool, int]:
        """Advance the simulator by δt, read self._frame; return (ego collision, new SV-SV contacts)."""
        raise NotImplementedError

    def _release(self, j: int) -> None:
        """SV j's cut-in arrived: give it back its own lane-change behaviour."""
        raise NotImplementedError

    def _move(self, mv: Move) -> None:
        """Recycling moved an SV: re-enter it in the simulator (and in self._frame, if it is not re-read)."""
        raise NotImplementedError

    def _after_moves(self) -> None:
        """After the recycling moves of a step: nothing by default (a backend may re-read its frame)."""

    # ------------------------------------------------------------------ the protocol
    def reset(self, mask: torch.Tensor | None = None, *, seed: int | None = None, episode: int | None = None) -> None:
        """Start the next episode of this seed (or episode `episode` of `seed`) if mask is None or True."""
        self._check_open()
        if mask is not None and not bool(torch.as_tensor(mask).reshape(-1)[0]):
            return
        self._core.new_episode(self._core.episode + 1 if episode is None else episode, seed)
        self._spawn_episode()

    def step(self, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        """Advance by δt with the ego tracking (target lane (1,) long, target speed (1,) m/s)."""
        self._check_open()
        core = self._core
        if self._ego_gone:
            return core.finish_step(self._frame, False, 0, ego_gone=True)
        target = int(torch.as_tensor(target_lane).reshape(-1)[0])
        speed = float(torch.as_tensor(target_speed, dtype=torch.float32).reshape(-1)[0])
        self._command_ego(core.accept_ego_target(self._frame, target), min(max(speed, 0.0), V_MAX_MPS))
        if core.adversarial:
            for j in core.adversarial_cut_ins(self._frame):
                self._cut_in(j, int(core.forced_lane[j]))
        collision, sv_collisions = self._simulate()
        f = self._frame
        for j in core.release_forced(f):
            self._release(j)
        moves = core.recycle(f)
        for mv in moves:
            self._move(mv)
        events = core.finish_step(f, collision, sv_collisions, ego_gone=self._ego_gone)
        if moves:
            self._after_moves()
        return events
