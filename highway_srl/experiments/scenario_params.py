"""Scenario parameters: knobs of an episode's initial scene that the falsifier's cross-entropy search
chooses (experiments/scenario_search.py), set on the state a World has just spawned.

The simulator is not changed: a World takes its state edited between steps, and these edits only choose
among initial scenes it could spawn or be given (wider gaps, other speeds in the spawn's range, other
driver styles, cut-in probabilities and trigger offsets of the vehicles placed at the start; vehicles
recycled later are drawn as always). An env with no parameters is the World's own spawn, bit for bit, so a case without them
replays as before. Every edit is a function of the env's own seed and parameters, so env b edited in a
batch and alone in a world of one env start the same.
"""

from __future__ import annotations

import math

import torch

from highway_srl.constants import STYLE_NAMES, STYLES, SV_INIT_SPEED_MPS, V_MAX_MPS
from highway_srl.sim import World, rng
from highway_srl.sim.idm_mobil import sorted_order

# name: (low, high). The style weights are relative (normalised over the three, at least one above 0).
# Gaps and speeds stay where the spawn puts them or move into benign room: a scene the spawn could not
# start (a leader closer or slower than its draws allow) can be past saving at step 0, which the
# ego-avoidable verdict, judging a few decisions before the contact, may still call avoidable.
KNOBS: dict[str, tuple[float, float]] = {
    "gap_scale": (1.0, 1.5),  # the SVs' drawn distances to the ego, scaled (1: as drawn; only wider)
    "sv_speed_mps": (-1.0, 1.0),  # added to every SV's drawn initial speed, kept in SV_INIT_SPEED_MPS
    "ego_speed_mps": SV_INIT_SPEED_MPS,  # the ego's initial speed instead of its draw from the same range
    "aggressive": (0.0, 1.0),  # weights of the SVs' styles, instead of a uniform draw
    "normal": (0.0, 1.0),
    "cautious": (0.0, 1.0),
    "cut_in_prob": (0.0, 1.0),  # ABP of every SV whose style has one (aggressive 1/9, cautious 1/27)
    "trigger_offset_m": (0.0, 10.0),  # every SV's |d_trig - d_SVi| instead of its draw from {0, 5, 10} m
}
STYLE_STREAM = 60  # the random stream of the style redraw (the simulator's streams are 0-7 and 20-24)


def check_parameters(parameters: dict) -> dict:
    """parameters, if each is a known knob with a finite number in its range (the style weights all three
    or none, not all 0); else a one-line ValueError."""
    if not isinstance(parameters, dict):
        raise ValueError(f"scenario parameters must be a mapping, got {type(parameters).__name__}")
    for name, value in parameters.items():
        if name not in KNOBS:
            raise ValueError(f"unknown scenario parameter {name!r}; choose from {', '.join(KNOBS)}")
        lo, hi = KNOBS[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
            raise ValueError(f"scenario parameter {name} must be a number in [{lo:g}, {hi:g}], got {value!r}")
    given = [name in parameters for name in STYLE_NAMES]
    if any(given) and not all(given):
        raise ValueError(f"give all three style weights ({', '.join(STYLE_NAMES)}) or none")
    if all(given) and not any(parameters[name] > 0 for name in STYLE_NAMES):
        raise ValueError("at least one style weight must be above 0")
    return parameters


def scenario_world(scene: str, level: str, adversarial: bool, seeds: list[int], steps: int, adversary: str,
                   parameters: list[dict]) -> World:
    """A world of len(seeds) envs, env b with seed seeds[b] and the scenario parameters parameters[b]
    (each checked; {} leaves that env's spawn as it is)."""
    if len(parameters) != len(seeds):
        raise ValueError(f"need one parameter set per env: {len(seeds)} seeds, {len(parameters)} sets")
    world = World(scene, level, adversarial, len(seeds), "cpu", list(seeds), max_steps=steps, adversary=adversary)
    if any(parameters):
        set_parameters(world, [check_parameters(p) for p in parameters])
    return world


def _column(parameters: list[dict], name: str) -> torch.Tensor:
    """(B, 1) float32: each env's value of knob `name`, NaN where it is not given."""
    return torch.tensor([[float(p.get(name, math.nan))] for p in parameters])


def set_parameters(world: World, parameters: list[dict]) -> None:
    """Edit the freshly spawned state of world's envs by their parameters (see KNOBS), in place."""
    s = world.state

    def put(field: torch.Tensor, value: torch.Tensor) -> None:  # where given; the ego's column left alone
        field[:, 1:] = torch.where(value.isnan(), field[:, 1:], value.to(field.dtype))

    weights = torch.cat([_column(parameters, name) for name in STYLE_NAMES], 1)  # (B, 3)
    if not bool(weights.isnan().all()):
        _set_styles(s, weights)
    put(s.adversarial_prob, torch.where(s.adversarial_prob[:, 1:] > 0, _column(parameters, "cut_in_prob"),
                                        s.adversarial_prob[:, 1:]))
    put(s.trigger_offset, _column(parameters, "trigger_offset_m"))
    put(s.x, s.x[:, :1] + (s.x[:, 1:] - s.x[:, :1]) * _column(parameters, "gap_scale"))
    put(s.v, (s.v[:, 1:] + _column(parameters, "sv_speed_mps")).clamp(*SV_INIT_SPEED_MPS))
    ego = _column(parameters, "ego_speed_mps")[:, 0]
    s.v[:, 0] = torch.where(ego.isnan(), s.v[:, 0], ego)
    s.order = sorted_order(s.x)  # scaling about the ego keeps the order; recomputed, not assumed


def _set_styles(s, weights: torch.Tensor) -> None:
    """Redraw the SVs' styles of the envs with weights (B, 3) (NaN rows keep theirs) and set what a style
    decides as spawn does: desired speed, headway, lane changes, ABP."""
    m = s.x.shape[1] - 1
    u = rng.uniform(rng.step_key(rng.episode_key(s.seed, s.episode), 0, STYLE_STREAM), m)  # (B, M)
    given = ~weights.isnan().any(1, keepdim=True)
    cum = torch.nan_to_num(weights).cumsum(1)
    cum = cum / cum[:, -1:].clamp(min=1e-12)
    style = (u[:, :, None] >= cum[:, None, :-1]).sum(2)  # (B, M) index into STYLES
    table = torch.tensor([[st.speed_violation, st.desired_headway_m, float(st.lane_change), st.adversarial_prob]
                          for st in STYLES], dtype=torch.float32)[style]  # (B, M, 4)
    keep = lambda field, value: torch.where(given, value.to(field.dtype), field[:, 1:])  # noqa: E731
    s.style[:, 1:] = keep(s.style, style)
    s.v0[:, 1:] = keep(s.v0, (1.0 + table[..., 0]) * V_MAX_MPS)
    s.s0[:, 1:] = keep(s.s0, table[..., 1])
    s.lane_change[:, 1:] = keep(s.lane_change, table[..., 2] > 0)
    s.adversarial_prob[:, 1:] = keep(s.adversarial_prob, table[..., 3])
