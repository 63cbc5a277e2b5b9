"""Ctrl-C and `kill` in a command with worker processes: the command says it in one line, its workers say nothing.

Ctrl-C reaches every process of the terminal's foreground group, the workers included. A worker left to
Python's default would raise KeyboardInterrupt wherever it stands (importing torch, waiting for work)
and print its traceback beside the command's line. So the command starts its workers with SIGINT and
SIGTERM held (blocked: held(), which they inherit across fork and exec), and each worker, once its own
handlers are set (quiet_worker), lets them through. SIGTERM in the command itself is raised as
Terminated, a KeyboardInterrupt, so that every clean-up written for Ctrl-C also runs for `kill`.

Before the command's main runs, Python imports for a second or more (gymnasium when highway_srl is
imported, then the CLI's modules), with nothing to clean up yet: quiet_start, the first thing the package
does when it is imported to run the command, makes Ctrl-C or `kill` meanwhile end it with the same line
and status at once; main then raises them as above (interrupts_raised).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager

SIGNALS = {signal.SIGINT, signal.SIGTERM}
COMMAND_MODULE, COMMAND_SCRIPT = "highway_srl.cli", "highway-srl"  # python -m highway_srl.cli; the console script


class Terminated(KeyboardInterrupt):
    """SIGTERM (`kill PID`), raised in the main thread where Ctrl-C raises KeyboardInterrupt."""


def stop_reason(err: KeyboardInterrupt) -> tuple[str, int]:
    """What stopped the command, in a word, and its exit status (128 + the signal's number)."""
    return ("terminated", 128 + signal.SIGTERM) if isinstance(err, Terminated) else ("interrupted", 128 + signal.SIGINT)


def _raise_terminated(signum, frame):
    raise Terminated


def runs_the_command() -> bool:
    """Whether this process was started to run the command: `highway-srl ...` (the console script, first on
    the interpreter's own command line) or `python -m highway_srl.cli ...` (while runpy imports the package
    to run the module, sys.argv[0] is "-m"). Any other process, a script or a worker, importing highway_srl
    is not."""
    argv = sys.orig_argv
    if sys.argv[0] == "-m":
        return COMMAND_MODULE in argv
    return len(argv) > 1 and os.path.basename(argv[1]) == COMMAND_SCRIPT


def stopped_while_starting(signum, frame):
    """Ctrl-C or `kill` before main: the command's one line and status, at once (nothing to clean up yet)."""
    word = "terminated" if signum == signal.SIGTERM else "interrupted"
    os.write(2, f"highway-srl: {word}\n".encode())
    os._exit(128 + signum)


def quiet_start() -> None:
    """In a process started to run the command (runs_the_command), Ctrl-C and `kill` end it with one line
    until main takes them over; a signal the process was started ignoring (a background job's Ctrl-C) stays
    ignored. Elsewhere (highway_srl imported as a library) nothing changes."""
    if not runs_the_command():
        return
    for sig in SIGNALS:
        if signal.getsignal(sig) in (signal.default_int_handler, signal.SIG_DFL):
            signal.signal(sig, stopped_while_starting)


@contextmanager
def interrupts_raised():
    """While the block runs in the main thread: SIGTERM raises Terminated, and SIGINT KeyboardInterrupt
    (Python's own handler, in place of quiet_start's), so that the command's clean-ups run; elsewhere a no-op."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {signal.SIGTERM: signal.signal(signal.SIGTERM, _raise_terminated)}
    if signal.getsignal(signal.SIGINT) is stopped_while_starting:
        before[signal.SIGINT] = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)


@contextmanager
def held():
    """SIGINT and SIGTERM blocked in this thread while the block starts worker processes (they start with
    them blocked, see quiet_worker); one that comes meanwhile is raised here at the block's end. The
    process's other threads (tqdm's monitor, a pool's) do not block them, and one of those may take the
    signal: so in the main thread the block also only notes a signal and raises it at its end, lest an
    interrupt land half-way through starting a worker (one that would then be no one's to end)."""
    noted = []
    handlers = {}
    if threading.current_thread() is threading.main_thread():
        handlers = {sig: signal.signal(sig, lambda signum, frame: noted.append(signum)) for sig in SIGNALS}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        if noted:
            signal.raise_signal(noted[0])  # through the handler the block found


def exit_at_once(signum, frame):
    """A worker's SIGINT handler: end now, without a word (the command reports the interrupt)."""
    os._exit(128 + signum)


def quiet_worker(on_interrupt=signal.SIG_IGN) -> None:
    """First thing in a worker started under held(): SIGINT to on_interrupt (ignored by default: the command
    that started the worker ends it), SIGTERM to the default (end without a word), then both let through."""
    signal.signal(signal.SIGINT, on_interrupt)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
