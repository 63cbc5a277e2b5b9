"""Ctrl-C and `kill` in a command with worker processes: the command says it in one line, its workers say nothing.

Ctrl-C reaches every process of the terminal's foreground group, the workers included. A worker left to
Python's default would raise KeyboardInterrupt wherever it stands (importing torch, waiting for work)
and print its traceback beside the command's line. So the command starts its workers with SIGINT and
SIGTERM held (blocked: held(), which they inherit across fork and exec), and each worker, once its own
handlers are set (quiet_worker), lets them through. SIGTERM in the command itself is raised as
Terminated, a KeyboardInterrupt, so that every clean-up written for Ctrl-C also runs for `kill`.
"""

from __future__ import annotations

import os
import signal
import threading
from contextlib import contextmanager

SIGNALS = {signal.SIGINT, signal.SIGTERM}


class Terminated(KeyboardInterrupt):
    """SIGTERM (`kill PID`), raised in the main thread where Ctrl-C raises KeyboardInterrupt."""


def stop_reason(err: KeyboardInterrupt) -> tuple[str, int]:
    """What stopped the command, in a word, and its exit status (128 + the signal's number)."""
    return ("terminated", 128 + signal.SIGTERM) if isinstance(err, Terminated) else ("interrupted", 128 + signal.SIGINT)


def _raise_terminated(signum, frame):
    raise Terminated


@contextmanager
def terminations_raised():
    """SIGTERM raises Terminated in this (the main) thread while the block runs; elsewhere a no-op."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)


@contextmanager
def held():
    """SIGINT and SIGTERM blocked in this thread while the block starts worker processes (they start with
    them blocked, see quiet_worker); one that comes meanwhile is raised here at the block's end."""
    before = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def exit_at_once(signum, frame):
    """A worker's SIGINT handler: end now, without a word (the command reports the interrupt)."""
    os._exit(128 + signum)


def quiet_worker(on_interrupt=signal.SIG_IGN) -> None:
    """First thing in a worker started under held(): SIGINT to on_interrupt (ignored by default: the command
    that started the worker ends it), SIGTERM to the default (end without a word), then both let through."""
    signal.signal(signal.SIGINT, on_interrupt)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
