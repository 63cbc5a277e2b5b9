"""torch.compile for the simulator and the trainer: the compile options of a static-shape graph, calls that
skip the guards once a graph has all its versions, and World's step as compiled graphs (CompiledStep).

Every graph here has static shapes and no break (fullgraph): the static step (sim/selection.py) reads no
value back to the host, so one step is one graph.
"""

from __future__ import annotations

import functools

import torch

from highway_srl.sim.events import StepEvents
from highway_srl.sim.state import WorldState, astuple_shallow
from highway_srl.sim.step import reset_compact, step_state

COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")

# A compiled graph's first WARM_CALLS calls (once all its versions exist) check every guard; later ones only
# those that tell its versions apart (call_settled). CHECK_GUARDS = True: every call checks them all.
WARM_CALLS = 2
CHECK_GUARDS = False


def compile_options(how: bool | str, device: torch.device) -> dict:
    """torch.compile's keywords for a static-shape graph: fullgraph (a graph break is an error), static
    shapes. how: True (the device's default: CUDA graphs on CUDA, mode "reduce-overhead"; C++ kernels on the
    CPU), a torch.compile mode, or a backend name ("eager", "aot_eager": graph capture without code
    generation, for checks). On the CPU, True also makes inductor's wrapper C++ (cpp_wrapper): the graph's
    kernels are then called from C++ instead of a generated Python function, which made one env's compiled
    step 1.2-1.4x faster (docs/benchmarks.md), for a longer compilation."""
    mode, backend, options = None, "inductor", None
    if how is True:
        if device.type == "cuda":
            mode = "reduce-overhead"
        else:
            options = {"cpp_wrapper": True}  # torch.compile takes a mode or options, not both
    elif how in COMPILE_MODES:
        mode = how
    else:
        backend = how
    # each World or Trainer adds cache entries for its methods' code (self and its constants are guarded
    # on); dynamo's default limit of 8 would refuse the ninth compiled one of a process under fullgraph
    torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, 256)
    return dict(fullgraph=True, mode=mode, backend=backend, dynamic=False, options=options)


def call_settled(graph, *args):
    """graph(*args), dynamo checking only the guards that tell graph's compiled versions apart
    (torch.compiler.set_stance's skip_guard_eval_unsafe), for a graph whose every version has been compiled
    and run: the callers (CompiledStep, trainer.compile_vector_step) say when that is.

    Why: dynamo checks every guard of a graph (each state tensor's metadata, each attribute the trace read) on
    every call: 80 us (one env's world step) to 200 us (a training graph) a call on this CPU, and a compiled
    MoE-RM-SRL training step makes 17 calls at 16 envs (collect, 16 update rounds): 2.8-3.5 ms of host time
    a vector step, more than its kernels on a GPU (docs/benchmarks.md). Why it is safe here: every graph has
    static shapes and reads no Python value that changes from call to call once its versions exist (the
    tests make a recompile an error, with CHECK_GUARDS on); a graph called with a new kind of input would
    silently run an old version instead of being recompiled, so nothing outside those callers should call
    this."""
    if CHECK_GUARDS:
        return graph(*args)
    with torch.compiler.set_stance("default", skip_guard_eval_unsafe=True):
        return graph(*args)


def uses_cuda_graphs(options: dict, device: torch.device) -> bool:
    """Whether a graph compiled with these compile_options replays as CUDA graphs (its outputs are then
    overwritten by its next replay: copy or consume them first)."""
    return device.type == "cuda" and options["backend"] == "inductor" and options["mode"] == "reduce-overhead"


def inference_mode_when_eager(fn):
    """fn in torch.inference_mode when it runs eagerly (a fifth of a single env's step is autograd bookkeeping
    otherwise); traced into a caller's graph (the trainer's compiled vector step), fn as it is: aot_autograd
    fails on an inference-mode region inside a graph ('Cannot set version_counter for inference tensor'), and
    a graph keeps no autograd bookkeeping of tensors that need no gradient anyway."""
    inference = torch.inference_mode()(fn)

    @functools.wraps(fn)
    def run(*args, **kwargs):
        return fn(*args, **kwargs) if torch.compiler.is_compiling() else inference(*args, **kwargs)

    return run


class CompiledStep:
    """How a compiled World steps (World(compile=...)): World.step, step_and_reset and reset(mask) of one
    world as torch.compile graphs of the static step; the methods of sim/step.py's EagerSteps.

    The graphs are pure (state tensors in, new state tensors out); the results are copied into the
    world's state tensors, which therefore stay the same objects that callers may hold. Under CUDA graphs
    the graph's outputs are overwritten by its next replay, hence the copy and the events' clone."""

    compiled, shares_state = True, False

    @property
    def worker_pids(self) -> list[int]:
        return []

    def __init__(self, world, how: bool | str):
        """world: the World whose state the graphs step (the one the methods are given); how: see
        compile_options."""
        self.world = world
        opts = compile_options(how, world.device)
        self.cuda_graphs = uses_cuda_graphs(opts, world.device)
        # torch.compile is lazy: only the graphs a caller uses are compiled
        self._step = torch.compile(self.pure_step, **opts)
        self._reset = torch.compile(self.pure_reset, **opts)
        self._step_reset = torch.compile(self.pure_step_reset, **opts)
        self._calls = {}  # per graph: each has one version (the world's settings are fixed), warm after WARM_CALLS

    def pure_step(self, state: tuple, target_lane: torch.Tensor, target_speed: torch.Tensor):
        w = self.world
        s = WorldState(*(t.clone() for t in state))
        ev = step_state(s, w.road, w.lane_tables, w.layout, w.level, target_lane, target_speed,
                        w.active_adversary, w.max_steps, static=True)
        return astuple_shallow(s), astuple_shallow(ev)

    def pure_reset(self, state: tuple, mask: torch.Tensor):
        return astuple_shallow(self.world.spawn_where(WorldState(*state), mask))

    def pure_step_reset(self, state: tuple, target_lane: torch.Tensor, target_speed: torch.Tensor):
        new, ev = self.pure_step(state, target_lane, target_speed)
        events = StepEvents(*ev)
        return self.pure_reset(new, events.terminated | events.truncated), ev

    def _call(self, graph, *args):
        """Run a compiled graph on the world's state; its new state is copied into the state's tensors."""
        if self.cuda_graphs:
            torch.compiler.cudagraph_mark_step_begin()
        calls = self._calls[graph] = self._calls.get(graph, 0) + 1
        run = call_settled if calls > WARM_CALLS else (lambda g, *a: g(*a))
        out = run(graph, astuple_shallow(self.world.state), *args)
        new, ev = out if graph is not self._reset else (out, None)
        torch._foreach_copy_(list(astuple_shallow(self.world.state)), list(new))
        if ev is not None:
            return StepEvents(*(e.clone() for e in ev) if self.cuda_graphs else ev)
        return None

    def step(self, world, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        return self._call(self._step, target_lane, target_speed)

    def step_and_reset(self, world, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        return self._call(self._step_reset, target_lane, target_speed)

    def reset(self, world, mask: torch.Tensor | None) -> None:
        if mask is None:  # every env: the compact reset spawns them all, no graph needed
            reset_compact(world, None)
        else:
            self.reset_where(world, mask)

    def reset_where(self, world, mask: torch.Tensor) -> None:
        self._call(self._reset, mask.reshape(world.num_envs))

    def close(self) -> None:
        pass
