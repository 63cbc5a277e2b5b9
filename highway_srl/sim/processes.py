"""One CPU World's envs stepped in several processes, on state in shared memory (World(processes=P)).

Why: on the CPU an eager step is a fixed ~1,000 operations whatever the batch, each with a dispatch cost,
and a second intra-op thread barely helps (1.1x: most operations are too small to split). Separate
processes each step a contiguous slice of the envs at once, so P cores do P slices' work in the time of
one slice. The fixed cost does not split (each process pays it for its slice): the gain grows with the
batch (docs/benchmarks.md has the figures).

How: the world's state tensors are moved to shared memory; this process steps the first slice itself and
P - 1 workers, forked from it, each step one of the others, through a view World over its slice of those
tensors (World.envs_view), so a step of a view updates the world's state in place and nothing is copied
back. The ego's commands and the step's events go through shared buffers; a pipe per worker carries only
the operation's name and the world's settings. Env b's draws depend only on its own seed and counters
(sim/rng.py), so a sharded world runs bit for bit the episodes of an unsharded one
(tests/sim/test_processes.py).

Waiting spins for up to SPIN_S before it blocks, on both sides. A blocked process is woken through the
scheduler: on the 2-core hosts measured, waking the workers and being woken by them cost 0.3-0.5 ms of a
9 ms step at 4,096 envs (the parent's send alone took 0.1-0.6 ms: the woken worker preempted it), and P
workers besides an idle parent were P + 1 processes for P cores. Stepping the first slice here and
spinning while the others finish made World(processes=2) 1.03-1.09x faster (docs/log/benchmarks-history.md, session 15).
A spin is bounded, so a world left idle between steps costs at most SPIN_S of each core after a step.
"""

from __future__ import annotations

import multiprocessing
import os
import time
import weakref

import torch

from highway_srl.interrupts import held, quiet_worker
from highway_srl.sim.events import STEP_EVENT_DTYPES, StepEvents

SPIN_S = 0.002  # seconds a waiting process polls before it blocks (see above)


def check_processes(processes, num_envs: int, compile, device: torch.device) -> None:
    """World's processes argument, or a one-line ValueError."""
    if not isinstance(processes, int) or not 1 <= processes <= num_envs:
        raise ValueError(f"processes must be an integer between 1 and num_envs ({num_envs}), got {processes!r}")
    if processes > 1 and (compile or device.type != "cpu"):
        raise ValueError("processes > 1 steps eager worlds on the CPU: use compile=False and device cpu")


def slices(num_envs: int, processes: int) -> list[tuple[int, int]]:
    """Contiguous env ranges [lo, hi) of near-equal size, one per process."""
    bounds = [num_envs * i // processes for i in range(processes + 1)]
    return list(zip(bounds[:-1], bounds[1:]))


class WorldProcesses:
    """How a World with processes = P > 1 steps: worker processes that step its envs in slices (see the
    module's docstring); the methods of sim/step.py's EagerSteps, for the one world it was made for."""

    compiled, shares_state = False, True

    def __init__(self, world, processes: int):
        try:
            ctx = multiprocessing.get_context("fork")
        except ValueError:
            raise ValueError("processes > 1 needs the fork start method (Linux or macOS)") from None
        b = world.num_envs
        for t in vars(world.state).values():
            t.share_memory_()
        self.lane = torch.zeros(b, dtype=torch.long).share_memory_()
        self.speed = torch.zeros(b, dtype=torch.float32).share_memory_()
        self.mask = torch.zeros(b, dtype=torch.bool).share_memory_()
        self.events = {name: torch.zeros(b, dtype=dtype).share_memory_() for name, dtype in STEP_EVENT_DTYPES.items()}
        self.conns, self.procs = [], []
        (lo, hi), *rest = slices(b, processes)
        self.local = (world.envs_view(lo, hi), lo, hi)  # this process steps the first slice itself
        self.local_name = f"highway-srl world {lo}:{hi} (this process)"
        for lo, hi in rest:
            parent_end, child_end = ctx.Pipe()
            # the child closes the parents' ends it inherits, so that it sees the parent go
            proc = ctx.Process(target=_serve, args=(child_end, [*self.conns, parent_end], world.envs_view(lo, hi),
                                                    lo, hi, self), daemon=True, name=f"highway-srl world {lo}:{hi}")
            with held():  # Ctrl-C is this process's to report: the worker starts deaf to it (interrupts.py)
                proc.start()
            child_end.close()
            self.conns.append(parent_end)
            self.procs.append(proc)
        self._finalizer = weakref.finalize(self, _stop, self.conns, self.procs)

    def call(self, op: str, settings: dict) -> None:
        """Run op ("step", "step_and_reset", "reset", "reset_all", "reset_where") on every slice and wait."""
        if not self._finalizer.alive:
            raise RuntimeError("this world's processes have been closed")
        try:
            failures = self._call(op, settings)
        except BaseException:
            # interrupted (Ctrl-C) with slices half stepped and replies unread: the world cannot go on
            self.close()
            raise
        if failures:
            self.close()
            raise RuntimeError("; ".join(f"world process {self.procs[i].name if i >= 0 else self.local_name} {why}"
                                         for i, why in failures.items()))

    def _call(self, op: str, settings: dict) -> dict:
        """call's work: the failures by slice (-1: this process's), as one line each."""
        failures = {}
        for i, conn in enumerate(self.conns):
            try:
                conn.send((op, settings))
            except OSError:  # its end of the pipe is gone
                failures[i] = _exited(self.procs[i])
        threads = torch.get_num_threads()
        torch.set_num_threads(1)  # one core per slice: the others are the workers'
        try:
            local_failure = _run(*self.local, self, op, settings)
        finally:
            torch.set_num_threads(threads)
        for i, conn in enumerate(self.conns):
            if i in failures:
                continue
            try:
                _spin(conn)
                reply = conn.recv()
            except (EOFError, OSError):
                reply = _exited(self.procs[i])
            if reply is not None:
                failures[i] = reply
        if local_failure is not None:
            failures[-1] = local_failure
        return failures

    def close(self) -> None:
        self._finalizer()

    @property
    def worker_pids(self) -> list[int]:
        return [p.pid for p in self.procs]

    def step(self, world, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        return self._step(world, "step", target_lane, target_speed)

    def step_and_reset(self, world, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        return self._step(world, "step_and_reset", target_lane, target_speed)

    def reset(self, world, mask: torch.Tensor | None) -> None:
        if mask is not None:
            self.mask.copy_(mask.reshape(world.num_envs))
        self._on_every_slice(world, "reset_all" if mask is None else "reset")

    def reset_where(self, world, mask: torch.Tensor) -> None:
        self.mask.copy_(mask.reshape(world.num_envs))
        self._on_every_slice(world, "reset_where")

    def _step(self, world, op: str, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents:
        self.lane.copy_(target_lane)
        self.speed.copy_(target_speed)
        self._on_every_slice(world, op)
        return StepEvents(**{name: buf.clone() for name, buf in self.events.items()})

    def _on_every_slice(self, world, op: str) -> None:
        """call(op) with the world's settings that a step reads (the workers' views have their own copies)."""
        self.call(op, {"static": world.static, "adversarial": world.adversarial, "adversary": world.adversary,
                       "max_steps": world.max_steps})


def _exited(proc) -> str:
    proc.join(timeout=5)
    code = proc.exitcode
    return f"exited ({f'killed by signal {-code}' if code is not None and code < 0 else f'exit code {code}'})"


def _stop(conns, procs) -> None:
    for conn in conns:
        try:
            conn.send(None)
        except OSError:
            pass
        conn.close()
    for proc in procs:
        proc.join(timeout=5)
        if proc.is_alive():
            proc.kill()


def _serve(conn, inherited, view, lo: int, hi: int, bufs: WorldProcesses) -> None:
    quiet_worker()  # Ctrl-C ignored: the parent reports it and closes this worker (call, close)
    # first of all: a forked child that runs an OpenMP region with the parent's thread count can hang in
    # libgomp (its pool belongs to the parent); one thread per process is the point of the processes anyway
    torch.set_num_threads(1)
    for end in inherited:
        end.close()
    parent = os.getppid()
    while True:
        try:
            _spin(conn)
            while not conn.poll(1.0):
                if os.getppid() != parent:  # the parent was killed: nobody will send again
                    return
            message = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if message is None:
            return
        op, settings = message
        reply = _run(view, lo, hi, bufs, op, settings)
        try:
            conn.send(reply)
        except OSError:  # the parent closed this world meanwhile (Ctrl-C): nobody waits for the reply
            return


def _spin(conn) -> None:
    """Poll conn until a message is there or SPIN_S has passed (the caller then blocks on it)."""
    deadline = time.perf_counter() + SPIN_S
    while not conn.poll(0) and time.perf_counter() < deadline:
        pass


def _run(view, lo: int, hi: int, bufs: WorldProcesses, op: str, settings: dict) -> str | None:
    """Run op on the slice lo:hi (view); None, or the failure as one line."""
    try:
        for name, value in settings.items():
            setattr(view, name, value)
        if op in ("step", "step_and_reset"):
            events = getattr(view, op)(bufs.lane[lo:hi], bufs.speed[lo:hi])
            for name, buf in bufs.events.items():
                buf[lo:hi] = getattr(events, name)
        elif op == "reset":
            view.reset(bufs.mask[lo:hi])
        elif op == "reset_all":
            view.reset()
        elif op == "reset_where":
            view.reset_where(bufs.mask[lo:hi])
        else:
            raise ValueError(f"unknown operation {op!r}")
        return None
    except Exception as e:  # reported by the parent as one line
        return f"failed: {type(e).__name__}: {e}"
