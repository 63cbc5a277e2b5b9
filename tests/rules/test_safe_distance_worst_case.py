"""The promise of R_SVi (§3.2, Eqs. 19-27), checked by brute-force simulation of the worst case.

If R = 1, the leader brakes at its maximum from now and the follower, after δt (accelerating at up to
3.5 m/s² when it is the ego, keeping its speed when it is the SV), brakes at its maximum, they never touch.
scripts/sd_sweep.py runs the same check on 10^6 random cases.
"""

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from highway_srl.rules import rule_indicator, safe_distance
from highway_srl.rules.worst_case import worst_case_collides

speeds = st.floats(0.0, 15.0, allow_nan=False)
brakes = st.floats(3.0, 9.0, allow_nan=False)
T = lambda x: torch.tensor([x], dtype=torch.float64)  # noqa: E731


@settings(max_examples=150, deadline=None, derandomize=True)
@given(gap=st.floats(-1.0, 40.0, allow_nan=False), v_ego=speeds, v_other=speeds, ego_brake=brakes,
       other_brake=brakes, front=st.booleans())
def test_vehicle_braking_never_collides_when_rule_says_safe(gap, v_ego, v_other, ego_brake, other_brake, front):
    r = rule_indicator(T(gap), T(v_ego), T(v_other), front=front, ego_brake=ego_brake, other_brake=other_brake)
    collides, min_gap = worst_case_collides(T(gap), T(v_ego), T(v_other), front=front, ego_brake=ego_brake,
                                            other_brake=other_brake)
    if bool(r):
        assert not bool(collides), f"R=1 but the worst case reaches gap {float(min_gap):.4f} m"


@settings(max_examples=100, deadline=None, derandomize=True)
@given(v_ego=speeds, v_other=speeds, ego_brake=brakes, other_brake=brakes, front=st.booleans())
def test_safe_distance_is_tight_a_centimetre_less_collides(v_ego, v_other, ego_brake, other_brake, front):
    kw = dict(front=front, ego_brake=ego_brake, other_brake=other_brake)
    d = float(safe_distance(T(v_ego), T(v_other), **kw))
    if d > 0.01:
        collides, _ = worst_case_collides(T(d - 0.01), T(v_ego), T(v_other), **kw)
        assert bool(collides)
    assert bool(rule_indicator(T(d + 0.01), T(v_ego), T(v_other), **kw))
    collides, _ = worst_case_collides(T(d + 0.01), T(v_ego), T(v_other), **kw)
    assert not bool(collides)


def test_literal_rule_breaks_the_promise_on_a_random_batch():
    """The printed Eqs. 21-27 accept some gaps that the paper's own constant-speed worst case closes."""
    g = torch.Generator().manual_seed(1)
    n = 4000
    u = lambda lo, hi: lo + (hi - lo) * torch.rand(n, generator=g, dtype=torch.float64)  # noqa: E731
    gap, v_e, v_o, a_e, a_o = u(0, 20), u(0, 15), u(0, 15), u(3, 9), u(3, 9)
    front = torch.rand(n, generator=g) < 0.5
    kw = dict(front=front, ego_brake=a_e, other_brake=a_o)
    collides, _ = worst_case_collides(gap, v_e, v_o, reaction_accel=0.0, **kw)
    assert (rule_indicator(gap, v_e, v_o, literal=True, **kw) & collides).any()
    assert not (rule_indicator(gap, v_e, v_o, **kw) & collides).any()
