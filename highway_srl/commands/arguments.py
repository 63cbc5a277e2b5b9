"""The CLI's argument types (argparse type= callables and their one-line errors) and shared options."""

from __future__ import annotations

import argparse
import math

from highway_srl.constants import TRAFFIC_LEVELS


def levels(text: str) -> list[str]:
    """--traffic for evaluate: 'C', 'c', 'A,C,F', 'A..F' or 'A-F' (either direction), in the order A..F.

    Anything else, an empty text or ',,' included, is an error rather than the training level."""
    t = text.replace(" ", "").upper()
    names = list(TRAFFIC_LEVELS)
    for sep in ("..", "-"):
        if sep in t:
            a, b = t.split(sep, 1)
            if a not in names or b not in names:
                raise argparse.ArgumentTypeError(f"unknown traffic range {text!r}; levels are {', '.join(names)}, "
                                                 "a range is written A..F")
            lo, hi = sorted((names.index(a), names.index(b)))
            return names[lo: hi + 1]
    parts = t.split(",")
    for x in parts:
        if x not in names:
            what = "an empty level" if not x else f"unknown traffic level {x!r}"
            raise argparse.ArgumentTypeError(f"{what} in {text!r}; choose from {', '.join(names)} (e.g. C, A,C,F or A..F)")
    return sorted(set(parts), key=names.index)


def level(text: str) -> str:
    """--traffic for the commands that run one level: 'C' or 'c'."""
    t = text.strip().upper()
    if t not in TRAFFIC_LEVELS:
        raise argparse.ArgumentTypeError(f"unknown traffic level {text!r}; choose one of {', '.join(TRAFFIC_LEVELS)}")
    return t


def _integer(text: str) -> int:
    """An integer, also written like 5e5 or 500_000 (the help texts quote the paper's 5e5)."""
    try:
        return _bounded(int(text), text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not math.isfinite(value) or not value.is_integer():
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}")
    return _bounded(int(value), text)


MAX_INTEGER = 2**53  # no count or number of steps comes near; above it a float's integers have gaps


def _bounded(value: int, text: str) -> int:
    if abs(value) > MAX_INTEGER:
        raise argparse.ArgumentTypeError(f"expected an integer of at most 2^53, got {text!r}")
    return value


def seed_number(text: str) -> int:
    """A seed: an integer from 0 to trainer.MAX_SEED (its streams stay inside a 64-bit generator seed)."""
    from highway_srl.agents.train_config import MAX_SEED

    value = _integer(text)
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected a seed from 0 to {MAX_SEED:,}, got {text!r}")
    return value


def positive(text: str) -> int:
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def non_negative(text: str) -> int:
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}")
    return value


def _number(text: str, what: str, ok) -> float:
    """A finite float for which ok(value) holds, else an argparse error "expected WHAT"."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if not math.isfinite(value) or not ok(value):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def positive_float(text: str) -> float:
    return _number(text, "a positive number", lambda v: v > 0)


def non_negative_float(text: str) -> float:
    return _number(text, "a non-negative number", lambda v: v >= 0)


def unit_fraction(text: str) -> float:
    return _number(text, "a number in (0, 1]", lambda v: 0 < v <= 1)


def profile_name(text: str) -> str:
    from highway_srl.rules import PROFILES

    if text not in PROFILES:
        raise argparse.ArgumentTypeError(f"unknown profile {text!r}; choose one of {', '.join(PROFILES)}")
    return text


def adversary_name(text: str) -> str:
    from highway_srl.sim.adversary import ADVERSARIES

    if text not in ADVERSARIES:
        raise argparse.ArgumentTypeError(f"unknown adversary {text!r}; choose one of {', '.join(ADVERSARIES)}")
    return text


def seed_list(text: str) -> tuple[int, ...]:
    try:
        seeds = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise ValueError(f"--seeds takes comma-separated integers, got {text!r}") from None
    if not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise ValueError(f"--seeds needs distinct non-negative integers, got {text!r}")
    return seeds


def step_form_args(p) -> None:
    """--static and --compile of train and bench: the form of the step (off by default on the CPU: compiling
    takes minutes and pays only over long runs, docs/benchmarks.md)."""
    p.add_argument("--static", action=argparse.BooleanOptionalAction, default=None,
                   help="the static-shape, sync-free step (masked resets and update rounds); default: on CUDA and "
                   "with --compile, the compact step on the CPU (faster there)")
    p.add_argument("--compile", action=argparse.BooleanOptionalAction, default=False,
                   help="torch.compile the static step (CUDA graphs on CUDA; a C++ compiler on the CPU, minutes of "
                   "compiling; eager is the reference); bench train reports eager and compiled side by side")

