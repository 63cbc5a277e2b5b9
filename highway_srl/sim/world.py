"""The batched highway world: reset, step and the ego's neighbour query, on CPU or CUDA.

A step is a fixed sequence of tensor operations over (B, N); there are no per-vehicle objects and no
Python loops over envs or vehicles (only over the at most three lanes).
"""

from __future__ import annotations

import copy
from dataclasses import fields

import torch

from highway_srl.constants import D_MAX_M, EPISODE_STEPS, STYLE_NAMES, TRAFFIC_LEVELS, VEHICLE_LENGTH_M
from highway_srl.scenarios import scenario_spec
from highway_srl.sim.allocator import keep_freed_memory
from highway_srl.sim.compiled import CompiledStep, astuple_shallow, inference_mode_when_eager
from highway_srl.sim.events import STEP_EVENT_DTYPES, StageFlags, StepEvents
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.processes import WorldProcesses, check_processes
from highway_srl.sim.road import Road, make_road
from highway_srl.sim.snapshot import LANE_END, NO_VEHICLE, Snapshot
from highway_srl.sim.spawn import Layout, make_layout, spawn
from highway_srl.sim.state import WorldState
from highway_srl.sim.step import check_command_types, check_command_values, step_state

MAX_VEHICLES = 64
ADVERSARIES = ("mild", "paper")  # group 3: adversary.safe_distance_cut_ins, adversary.paper_cut_ins


def check_device(device: str | torch.device) -> torch.device:
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"unknown device {device!r}; use cpu, cuda or cuda:N") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} is not available here (no CUDA); use cpu")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise ValueError(f"device {device!r} does not exist; {torch.cuda.device_count()} CUDA device(s) found")
    if dev.type not in ("cpu", "cuda"):
        raise ValueError(f"unsupported device {device!r}; use cpu, cuda or cuda:N")
    return dev


class World:
    """B independent episodes of one scenario and traffic level.

    seed: an int (env b gets seed + b) or a sequence of B ints. Env b's episodes depend only on its own
    seed, not on the batch size or the device's other envs. adversary: which group-3 cut-ins run when
    adversarial is True, "mild" (ours: ahead of the ego, with room, beyond its safe distance) or "paper"
    (§4.3 as printed); both in sim/adversary.py.

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
        adversary: str = "mild",
        compile: bool | str = False,
        processes: int = 1,
    ):
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
        if isinstance(seed, int):
            seeds = torch.arange(num_envs, dtype=torch.long) + seed
        else:
            seeds = torch.as_tensor(list(seed), dtype=torch.long)
            if seeds.shape != (num_envs,):
                raise ValueError(f"need {num_envs} seeds, got {seeds.shape[0]}")
        self._lane_tables = LaneTables.of(self.road, self.device)
        self._processes: WorldProcesses | None = None
        self.state = spawn(
            self.road, level, self.layout, seeds.to(self.device), torch.zeros_like(seeds).to(self.device), self.style
        )
        self._compiled = CompiledStep(self, compile) if compile else None
        # eager steps in the static form (no host read; bit-identical, more work: a sync-free loop on a GPU)
        self.static = False
        if processes > 1:
            self._processes = WorldProcesses(self, processes, STEP_EVENT_DTYPES)

    @property
    def state(self) -> WorldState:
        return self._state

    @state.setter
    def state(self, new: WorldState) -> None:
        """Replace the state; with worker processes, copied into the shared tensors they step (same shapes)."""
        if self._processes is None:
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
        view.num_envs, view._compiled, view._processes = hi - lo, None, None
        view._state = WorldState(**{f.name: getattr(self._state, f.name)[lo:hi] for f in fields(self._state)})
        return view

    @property
    def worker_pids(self) -> list[int]:
        """The process ids of the P - 1 worker processes (processes = P > 1), else []."""
        return [] if self._processes is None else [p.pid for p in self._processes.procs]

    def close(self) -> None:
        """End the worker processes (processes > 1); the world then steps no more. A no-op otherwise."""
        if self._processes is not None:
            self._processes.close()

    def _in_processes(self, op: str) -> None:
        self._processes.call(op, {"static": self.static, "adversarial": self.adversarial,
                                  "adversary": self.adversary, "max_steps": self.max_steps})

    # ------------------------------------------------------------------ episodes
    @inference_mode_when_eager
    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Start new episodes in the envs where mask (B,) is True (all envs if None)."""
        s = self.state
        if self._compiled is not None and mask is not None:
            self._compiled.reset(mask)
            return
        if self._processes is not None:
            if mask is not None:
                self._processes.mask.copy_(mask.reshape(self.num_envs))
            self._in_processes("reset_all" if mask is None else "reset")
            return
        idx = torch.arange(self.num_envs, device=self.device) if mask is None else mask.nonzero().squeeze(1)
        if idx.numel() == 0:
            return
        fresh = spawn(self.road, self.level, self.layout, s.seed[idx], s.episode[idx] + 1, self.style)
        s.index_put(idx, fresh)

    @inference_mode_when_eager
    def reset_where(self, mask: torch.Tensor) -> None:
        """reset(mask) in the static form: a masked select of a full spawn, no host read (the same
        values; compiled worlds always reset this way). Costs a spawn of every env."""
        if self._compiled is not None:
            self._compiled.reset(mask.reshape(self.num_envs))
            return
        if self._processes is not None:
            self._processes.mask.copy_(mask.reshape(self.num_envs))
            self._in_processes("reset_where")
            return
        fresh = self.spawn_where(self.state, mask)
        torch._foreach_copy_(list(astuple_shallow(self.state)), list(astuple_shallow(fresh)))

    @inference_mode_when_eager
    def step(self, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        """Advance every env by δt with the ego tracking (target lane (B,) long, target speed (B,) m/s).

        Runs in inference mode (a fifth of a single env's step is autograd bookkeeping otherwise); the
        state is updated in place, so its tensors stay ordinary ones that callers may edit. The returned
        events are inference tensors: read them, combine them, or clone them before editing in place."""
        s = self.state
        target_lane, target_speed = self._commands(target_lane, target_speed)
        if self._compiled is not None:
            return self._compiled.step(target_lane, target_speed)
        if self._processes is not None:
            return self._step_in_processes("step", target_lane, target_speed)
        return step_state(s, self.road, self._lane_tables, self.layout, self.level, target_lane, target_speed,
                          self.active_adversary, self.max_steps, static=self.static)

    def _step_in_processes(self, op: str, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        self._processes.lane.copy_(target_lane)
        self._processes.speed.copy_(target_speed)
        self._in_processes(op)
        return StepEvents(**{name: buf.clone() for name, buf in self._processes.events.items()})

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
        return self._compiled is None and lane.device.type == "cpu" and speed.device.type == "cpu"

    @inference_mode_when_eager
    def step_and_reset(self, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        """step, then new episodes where it terminated or truncated (the events are the step's): one graph
        when compiled; eager, a reset only when some env is done (a host read)."""
        if self._compiled is not None:
            return self._compiled.step_and_reset(*self._commands(target_lane, target_speed))
        if self._processes is not None:
            return self._step_in_processes("step_and_reset", *self._commands(target_lane, target_speed))
        events = self.step(target_lane, target_speed)
        done = events.terminated | events.truncated
        if bool(done.any()):
            self.reset(done)
        return events

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

    def neighbours(self, current_lane: torch.Tensor, adjacent_lane: torch.Tensor, d_max: float = D_MAX_M) -> Snapshot:
        """SV1..SV4 of the ego: nearest front/rear vehicle in current_lane and adjacent_lane (B,) within d_max
        (see ego_neighbours)."""
        return ego_neighbours(self.state, self.road, self._lane_tables, current_lane, adjacent_lane, d_max)


def ego_neighbours(s: WorldState, road: Road, tables: LaneTables, current_lane: torch.Tensor,
                   adjacent_lane: torch.Tensor, d_max: float = D_MAX_M) -> Snapshot:
    """SV1..SV4 of the ego: nearest front/rear vehicle in current_lane and adjacent_lane (B,) within d_max.

    Reads s.x, s.y, s.v, s.heading, s.lane (B, N). Lane membership is by the nearest lane centre; 'front'
    means the SV's centre is ahead of the ego's. The end of a dropped lane ahead appears as a standing
    vehicle whose rear bumper is at the lane end.
    """
    x, lane = s.x[:, 1:], s.lane[:, 1:]
    ego_x = s.x[:, 0]
    dx = x - ego_x[:, None]
    near = dx.abs() <= d_max
    inf = torch.full_like(dx, float("inf"))
    slots = []
    for lane_q in (current_lane, adjacent_lane):
        in_lane = (lane == lane_q[:, None]) & near
        front_d, front_i = torch.where(in_lane & (dx > 0), dx, inf).min(1)
        rear_d, rear_i = torch.where(in_lane & (dx <= 0), -dx, inf).min(1)
        slots.append((front_d, front_i, lane_q))
        slots.append((rear_d, rear_i, lane_q))
    order = (0, 2, 1, 3)  # SV1 front-current, SV2 front-adjacent, SV3 rear-current, SV4 rear-adjacent
    dist = torch.stack([slots[k][0] for k in order], 1)
    idx = torch.stack([slots[k][1] for k in order], 1) + 1
    valid = torch.isfinite(dist)
    gx = lambda t: torch.gather(t, 1, idx)  # noqa: E731
    sv_x, sv_y, sv_v, sv_h = gx(s.x), gx(s.y), gx(s.v), gx(s.heading)
    sv_index = torch.where(valid, idx, NO_VEHICLE)
    # lane ends ahead (merge on-ramp): a standing obstacle if nearer than the front vehicle
    end = tables.drop_end_m
    for k, lane_q in ((0, current_lane), (1, adjacent_lane)):
        lane_end = end[lane_q.clamp(min=0)]
        wall_x = lane_end + 0.5 * VEHICLE_LENGTH_M
        use = (lane_q >= 0) & (wall_x - ego_x <= d_max) & (~valid[:, k] | (wall_x < sv_x[:, k]))
        use &= torch.isfinite(lane_end) & (wall_x > ego_x)
        sv_x[:, k] = torch.where(use, wall_x, sv_x[:, k])
        sv_y[:, k] = torch.where(use, lane_q.float() * road.lane_width_m, sv_y[:, k])
        sv_v[:, k] = torch.where(use, 0.0, sv_v[:, k])
        sv_h[:, k] = torch.where(use, 0.0, sv_h[:, k])
        sv_index[:, k] = torch.where(use, LANE_END, sv_index[:, k])
        valid[:, k] |= use
    zero = torch.zeros_like(sv_x)
    return Snapshot(
        ego_x=ego_x,
        ego_y=s.y[:, 0],
        ego_vx=s.v[:, 0] * torch.cos(s.heading[:, 0]),
        ego_vy=s.v[:, 0] * torch.sin(s.heading[:, 0]),
        ego_heading=s.heading[:, 0],
        ego_lane=s.lane[:, 0],
        sv_x=torch.where(valid, sv_x, zero),
        sv_y=torch.where(valid, sv_y, zero),
        sv_vx=torch.where(valid, sv_v * torch.cos(sv_h), zero),
        sv_vy=torch.where(valid, sv_v * torch.sin(sv_h), zero),
        sv_heading=torch.where(valid, sv_h, zero),
        sv_valid=valid,
        sv_index=sv_index,
        current_lane=current_lane,
        adjacent_lane=adjacent_lane,
    )
