"""The batched highway world: B episodes of one scenario and traffic level, reset, stepped and queried
together on CPU or CUDA (World).

How a world steps is chosen once, when it is made: eagerly in this process (sim/step.py, the reference),
as compiled graphs (sim/compiled.py) or in worker processes (sim/processes.py); World's methods check
their arguments and hand the work to that choice.
"""

from __future__ import annotations

import copy
from dataclasses import fields

import torch

from highway_srl.constants import DEFAULT_ADVERSARY, D_MAX_M, EPISODE_STEPS, STYLE_NAMES, TRAFFIC_LEVELS, TrafficLevel
from highway_srl.scenarios import scenario_spec
from highway_srl.sim.adversary import ADVERSARIES
from highway_srl.sim.allocator import keep_freed_memory
from highway_srl.sim.compiled import CompiledStep, inference_mode_when_eager
from highway_srl.sim.device import check_device
from highway_srl.sim.events import StageFlags, StepEvents
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.processes import WorldProcesses, check_processes
from highway_srl.sim.road import Road, make_road
from highway_srl.sim.snapshot import Snapshot, ego_neighbours
from highway_srl.sim.spawn import Layout, make_layout, spawn
from highway_srl.sim.state import WorldState
from highway_srl.sim.step import EAGER, check_command_types, check_command_values

MAX_VEHICLES = 64


class World:
    """B independent episodes of one scenario and traffic level.

    seed: an int (env b gets seed + b) or a sequence of B ints. Env b's episodes depend only on its own
    seed, not on the batch size or the device's other envs. adversary: which group-3 cut-ins run when
    adversarial is True, "mild" (ours: ahead of the ego, with room, beyond its safe distance) or "paper"
    (§4.3 as printed); both in sim/adversary.py. Its default is every entry point's (constants.DEFAULT_ADVERSARY,
    the reproduction's): a World made without it runs the cut-ins that train, evaluate and the envs run.

    compile: run step and reset as compiled static-shape graphs (sim/compiled.py): False (eager, the
    reference), True (torch.compile; on CUDA with CUDA graphs, mode "reduce-overhead") or a torch.compile
    mode. The compiled step follows eager to float rounding (tests/sim/test_compile.py); eager runs
    reproduce bit for bit. On the CPU it needs a C++ compiler.

    processes: step the envs in this many processes of one thread each, P contiguous slices of the batch:
    this one steps the first slice, P - 1 forked workers the others (CPU, eager; sim/processes.py): the
    same episodes bit for bit, faster at large batches on several cores. The state stays readable and
    editable in this process between steps; close() ends the workers.

    check_commands: whether step and step_and_reset check the values of their commands (lanes of the road,
    finite speeds >= 0; their dtype and count are always checked). None (the default): in an eager world
    when the commands are in host memory (a Python number, a list, a NumPy array or a CPU tensor: a read of
    memory this process holds, ~20 us); not for commands already on a CUDA device, where a read would wait
    for the device at every step, nor in a compiled world, whose step is short enough for a read to show.
    True: always (a debugging aid on CUDA); False: never. Speeds above v_max are valid: the ego's
    controller clamps its target to v_max.
    """

    check_commands: bool | None = None

    def __init__(
        self,
        scenario: str = "two-lane",
        traffic: str = "C",
        adversarial: bool = False,
        num_envs: int = 1,
        device: str | torch.device = "cpu",
        seed: int | list[int] = 0,
        style: str | None = None,
        num_vehicles: int | None = None,
        max_steps: int = EPISODE_STEPS,
        adversary: str = DEFAULT_ADVERSARY,
        compile: bool | str = False,
        processes: int = 1,
    ):
        level, m = check_world_args(scenario, traffic, num_envs, style, num_vehicles, max_steps, adversary)
        self.adversary = adversary
        self.device = check_device(device)
        check_processes(processes, num_envs, compile, self.device)
        if self.device.type == "cpu":
            keep_freed_memory()  # 1.2x at 4,096 envs: the step's freed tensors are reused, not faulted in again
        self.scenario, self.traffic, self.adversarial = scenario, traffic, bool(adversarial)
        self.road: Road = make_road(scenario)
        self.level = level
        self.layout: Layout = make_layout(self.road, level, m)
        self.num_envs, self.num_vehicles = num_envs, m + 1
        self.max_steps = max_steps
        self.style = None if style is None else STYLE_NAMES.index(style)
        seeds = seed_tensor(seed, num_envs)
        self._lane_tables = LaneTables.of(self.road, self.device)
        self._state = spawn(
            self.road, level, self.layout, seeds.to(self.device), torch.zeros_like(seeds).to(self.device), self.style
        )
        # eager steps in the static form (no host read; bit-identical, more work: a sync-free loop on a GPU)
        self.static = False
        # how this world steps, chosen once: EAGER, CompiledStep or WorldProcesses (the same methods)
        self._steps = EAGER
        if compile:
            self._steps = CompiledStep(self, compile)
        elif processes > 1:
            self._steps = WorldProcesses(self, processes)

    @property
    def state(self) -> WorldState:
        return self._state

    @state.setter
    def state(self, new: WorldState) -> None:
        """Replace the state; with worker processes, copied into the shared tensors they step (same shapes)."""
        if not self._steps.shares_state:
            self._state = new
            return
        for f in fields(new):
            mine, theirs = getattr(self._state, f.name), getattr(new, f.name)
            if mine.shape != theirs.shape:
                raise ValueError(f"state field {f.name} has shape {tuple(theirs.shape)}, this world's "
                                 f"{tuple(mine.shape)}")
            mine.copy_(theirs)

    def envs_view(self, lo: int, hi: int) -> "World":
        """A World over envs lo..hi-1 of this one (eager), on views of this world's state tensors: stepping
        or resetting the view steps or resets those envs of this world in place."""
        if not 0 <= lo < hi <= self.num_envs:
            raise ValueError(f"envs_view needs 0 <= lo < hi <= {self.num_envs}, got {lo}, {hi}")
        view = copy.copy(self)
        view.num_envs, view._steps = hi - lo, EAGER
        view._state = WorldState(**{f.name: getattr(self._state, f.name)[lo:hi] for f in fields(self._state)})
        return view

    @property
    def worker_pids(self) -> list[int]:
        """The process ids of the P - 1 worker processes (processes = P > 1), else []."""
        return self._steps.worker_pids

    def close(self) -> None:
        """End the worker processes (processes > 1); the world then steps no more. A no-op otherwise."""
        self._steps.close()

    # ------------------------------------------------------------------ episodes
    @inference_mode_when_eager
    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Start new episodes in the envs where mask (B,) is True (all envs if None)."""
        self._steps.reset(self, mask)

    @inference_mode_when_eager
    def reset_where(self, mask: torch.Tensor) -> None:
        """reset(mask) in the static form: a masked select of a full spawn, no host read (the same
        values; compiled worlds always reset this way). Costs a spawn of every env."""
        self._steps.reset_where(self, mask)

    @inference_mode_when_eager
    def step(self, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        """Advance every env by δt with the ego tracking (target lane (B,) long, target speed (B,) m/s).

        Runs in inference mode (a fifth of a single env's step is autograd bookkeeping otherwise); the
        state is updated in place, so its tensors stay ordinary ones that callers may edit. The returned
        events are inference tensors: read them, combine them, or clone them before editing in place."""
        return self._steps.step(self, *self._commands(target_lane, target_speed))

    @inference_mode_when_eager
    def step_and_reset(self, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        """step, then new episodes where it terminated or truncated (the events are the step's): one graph
        when compiled; eager, a reset only when some env is done (a host read)."""
        return self._steps.step_and_reset(self, *self._commands(target_lane, target_speed))

    @property
    def active_adversary(self) -> str | None:
        """The group-3 adversary that runs ("mild" or "paper"), None in nominal traffic."""
        return self.adversary if self.adversarial else None

    def _commands(self, target_lane, target_speed) -> tuple[torch.Tensor, torch.Tensor]:
        """The ego's commands as (B,) long lanes and (B,) float32 speeds on the world's device, checked first
        (check_commands): a float lane, a wrong count, a lane off the road or a non-finite or negative speed
        is one ValueError, before anything is stepped."""
        lane, speed = torch.as_tensor(target_lane), torch.as_tensor(target_speed)  # host values: on the CPU
        check_command_types(lane, speed, self.num_envs)
        if self._reads_commands(lane, speed):
            check_command_values(lane, speed, self.road.num_lanes)
        lane = lane.to(self.device).long().reshape(self.num_envs)
        return lane, speed.to(self.device, torch.float32).reshape(self.num_envs)

    def _reads_commands(self, lane: torch.Tensor, speed: torch.Tensor) -> bool:
        """Whether step reads its commands' values to check them (see check_commands)."""
        if torch.compiler.is_compiling():
            return False  # traced into a caller's graph: a read would break it
        if self.check_commands is not None:
            return self.check_commands
        return not self._steps.compiled and lane.device.type == "cpu" and speed.device.type == "cpu"

    def spawn_where(self, s: WorldState, mask: torch.Tensor) -> WorldState:
        """State s with fresh episodes (episode + 1) in the envs where mask (B,) is True: a masked select
        of a full spawn, static shapes (the compact reset spawns only the masked envs; same values)."""
        fresh = spawn(self.road, self.level, self.layout, s.seed, s.episode + 1, self.style)
        return WorldState(**{
            f.name: torch.where(mask.reshape((-1,) + (1,) * (getattr(s, f.name).dim() - 1)),
                                getattr(fresh, f.name), getattr(s, f.name))
            for f in fields(s)
        })

    # ------------------------------------------------------------------ queries
    @property
    def ego_lane(self) -> torch.Tensor:
        return self.state.lane[:, 0]

    @property
    def ego_speed(self) -> torch.Tensor:
        return self.state.v[:, 0]

    @property
    def lane_tables(self) -> LaneTables:
        """The road's per-lane lookup tables on this world's device (read-only use)."""
        return self._lane_tables

    def adversary_counts(self) -> dict[str, torch.Tensor]:
        """Group-3 counters of the current episodes (B,) long: triggers (trigger draws made) and cut_ins
        (forced lane changes started); zero in nominal traffic, reset with each episode."""
        s = self.state
        return {"triggers": s.adv_triggers.clone(), "cut_ins": s.adv_cut_ins.clone()}

    def stage_flags(self) -> StageFlags:
        """Latched task stages of the current episodes (the state's own tensors, updated in place by step)."""
        s = self.state
        return StageFlags(s.merged, s.exit1, s.exit2)

    def neighbours(self, current_lane: torch.Tensor, adjacent_lane: torch.Tensor, d_max: float = D_MAX_M,
                   by_body: bool = False) -> Snapshot:
        """SV1..SV4 of the ego: nearest front/rear vehicle in current_lane and adjacent_lane (B,) within d_max,
        lanes by centre or by_body (see ego_neighbours)."""
        return ego_neighbours(self.state, self.road, self._lane_tables, current_lane, adjacent_lane, d_max, by_body)


def check_world_args(scenario: str, traffic: str, num_envs, style: str | None, num_vehicles, max_steps,
                     adversary: str) -> tuple[TrafficLevel, int]:
    """World's arguments, or a one-line ValueError; returns the traffic level and the number of SVs."""
    scenario_spec(scenario)  # raises the one-line error naming the scenarios
    if traffic not in TRAFFIC_LEVELS:
        raise ValueError(f"unknown traffic level {traffic!r}; choose one of {', '.join(TRAFFIC_LEVELS)}")
    if not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
    if style is not None and style not in STYLE_NAMES:
        raise ValueError(f"unknown driving style {style!r}; choose one of {', '.join(STYLE_NAMES)} or none")
    level = TRAFFIC_LEVELS[traffic]
    m = level.num_vehicles if num_vehicles is None else num_vehicles
    if not isinstance(m, int) or m < 1 or m + 1 > MAX_VEHICLES:
        raise ValueError(f"num_vehicles must be between 1 and {MAX_VEHICLES - 1}, got {m!r}")
    if not isinstance(max_steps, int) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    if adversary not in ADVERSARIES:
        raise ValueError(f"unknown adversary {adversary!r}; choose one of {', '.join(ADVERSARIES)}")
    return level, m


def seed_tensor(seed: int | list[int], num_envs: int) -> torch.Tensor:
    """(B,) long seeds: seed + b for an int, else the B given ones (a one-line ValueError for another count)."""
    if isinstance(seed, int):
        return torch.arange(num_envs, dtype=torch.long) + seed
    seeds = torch.as_tensor(list(seed), dtype=torch.long)
    if seeds.shape != (num_envs,):
        raise ValueError(f"need {num_envs} seeds, got {seeds.shape[0]}")
    return seeds
