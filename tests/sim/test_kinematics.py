"""One step's longitudinal kinematics (sim.dynamics.integrate_speed): constant acceleration over δt, exact
where a car stops or the ego reaches its speed limit within the step (golden values worked by hand)."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from highway_srl.constants import DT_S, V_MAX_MPS
from highway_srl.sim.dynamics import integrate_speed


def _one(v_ego: float, a_ego: float, v_sv: float, a_sv: float) -> tuple[list[float], list[float]]:
    v = torch.tensor([[v_ego, v_sv]])
    a = torch.tensor([[a_ego, a_sv]])
    v_new, v_mean = integrate_speed(v, a, DT_S, V_MAX_MPS)
    return v_new[0].tolist(), (v_mean[0] * DT_S).tolist()


@pytest.mark.parametrize("v, a, v_end, dist", [
    # stops mid-step: v^2 / (2|a|) = 0.44^2 / 12 = 0.0161333 m (the trapezoid gave 0.0275 m)
    (0.44, -6.0, 0.0, 0.44**2 / 12.0),
    # 1.0 m/s at -9: stops after 0.111 s, 1 / 18 m
    (1.0, -9.0, 0.0, 1.0 / 18.0),
    # no stop: v dt + a dt^2 / 2 = 0.625 - 0.015625
    (5.0, -2.0, 4.75, 0.609375),
    # standing and braking stays put
    (0.0, -3.0, 0.0, 0.0),
    # exactly reaching 0 at the step's end: the trapezoid is exact there
    (0.75, -6.0, 0.0, 0.046875),
])
def test_a_car_that_stops_within_the_step_stops_where_exact_kinematics_put_it(v, a, v_end, dist):
    for column in (0, 1):  # the ego and a surrounding vehicle alike
        args = (v, a, 5.0, 0.0) if column == 0 else (5.0, 0.0, v, a)
        v_new, travelled = _one(*args)
        assert v_new[column] == pytest.approx(v_end, abs=1e-7)
        assert travelled[column] == pytest.approx(dist, abs=1e-7)


def test_the_ego_reaching_its_limit_mid_step_drives_on_at_the_limit():
    # 9.9 m/s at +2: the limit after 0.05 s; 9.9 * 0.05 + 0.0025 + 10 * 0.075 = 1.2475 m
    v_new, travelled = _one(9.9, 2.0, 9.9, 2.0)
    assert v_new == pytest.approx([V_MAX_MPS, 9.9 + 2.0 * DT_S])
    assert travelled[0] == pytest.approx(1.2475, abs=1e-6)
    assert travelled[1] == pytest.approx(9.9 * DT_S + 0.5 * 2.0 * DT_S**2, abs=1e-6)  # no limit for SVs


@settings(max_examples=200, deadline=None)
@given(v=st.floats(0.0, 10.0), a=st.floats(-9.0, 4.0))
def test_distance_is_the_integral_of_the_clamped_speed(v, a):
    """Against a fine numerical integral of max(0, v + a t), capped at the ego's limit for column 0."""
    t = torch.linspace(0.0, DT_S, 20_001, dtype=torch.float64)
    speed = (v + a * t).clamp(min=0.0)
    v_new, travelled = _one(v, a, v, a)
    for column, cap in ((0, V_MAX_MPS), (1, float("inf"))):
        exact = float(torch.trapezoid(speed.clamp(max=max(cap, v)), t))
        assert travelled[column] == pytest.approx(exact, abs=2e-6)
