"""One CPU World's envs stepped in several worker processes, on state in shared memory (World(processes=P)).

Why: on the CPU an eager step is a fixed ~900 operations whatever the batch, each with a dispatch cost,
and a second intra-op thread barely helps (1.1x: most operations are too small to split). Separate
processes each step a contiguous slice of the envs at once, so P cores do P slices' work in the time of
one slice. The fixed cost does not split (each process pays it for its slice): the gain grows with the
batch (docs/benchmarks.md has the figures).

How: the world's state tensors are moved to shared memory; each worker is forked from the parent with a view
World over its slice of those tensors (World.envs_view), so a step of the view updates the parent's state
in place and nothing is copied back. The ego's commands and the step's events go through shared buffers;
a pipe per worker carries only the operation's name and the world's settings. Env b's draws depend only
on its own seed and counters (sim/rng.py), so a sharded world runs bit for bit the episodes of an
unsharded one (tests/sim/test_processes.py).
"""

from __future__ import annotations

import multiprocessing
import os
import weakref

import torch


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
    """Worker processes that step the envs of `world` in slices (see the module's docstring); event_dtypes:
    the step's events by name and dtype (world.STEP_EVENT_DTYPES), one shared (B,) buffer each."""

    def __init__(self, world, processes: int, event_dtypes: dict[str, torch.dtype]):
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
        self.events = {name: torch.zeros(b, dtype=dtype).share_memory_() for name, dtype in event_dtypes.items()}
        self.conns, self.procs = [], []
        for lo, hi in slices(b, processes):
            parent_end, child_end = ctx.Pipe()
            # the child closes the parents' ends it inherits, so that it sees the parent go
            proc = ctx.Process(target=_serve, args=(child_end, [*self.conns, parent_end], world.envs_view(lo, hi),
                                                    lo, hi, self), daemon=True, name=f"highway-srl world {lo}:{hi}")
            proc.start()
            child_end.close()
            self.conns.append(parent_end)
            self.procs.append(proc)
        self._finalizer = weakref.finalize(self, _stop, self.conns, self.procs)

    def call(self, op: str, settings: dict) -> None:
        """Run op ("step", "step_and_reset", "reset", "reset_all", "reset_where") in every worker and wait."""
        if not self._finalizer.alive:
            raise RuntimeError("this world's processes have been closed")
        failures = {}
        for i, conn in enumerate(self.conns):
            try:
                conn.send((op, settings))
            except OSError:  # its end of the pipe is gone
                failures[i] = _exited(self.procs[i])
        for i, conn in enumerate(self.conns):
            if i in failures:
                continue
            try:
                reply = conn.recv()
            except (EOFError, OSError):
                reply = _exited(self.procs[i])
            if reply is not None:
                failures[i] = reply
        if failures:
            self.close()
            raise RuntimeError("; ".join(f"world process {self.procs[i].name} {why}" for i, why in failures.items()))

    def close(self) -> None:
        self._finalizer()


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
    # first of all: a forked child that runs an OpenMP region with the parent's thread count can hang in
    # libgomp (its pool belongs to the parent); one thread per process is the point of the processes anyway
    torch.set_num_threads(1)
    for end in inherited:
        end.close()
    parent = os.getppid()
    while True:
        try:
            while not conn.poll(1.0):
                if os.getppid() != parent:  # the parent was killed: nobody will send again
                    return
            message = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if message is None:
            return
        op, settings = message
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
            conn.send(None)
        except Exception as e:  # reported by the parent as one line
            conn.send(f"failed: {type(e).__name__}: {e}")
