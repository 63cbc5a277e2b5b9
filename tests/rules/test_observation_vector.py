"""The 37 network inputs (§3.1 S* + R*_SV + u*, §4.1) and their documented ranges."""

import torch

from highway_srl.constants import OBS_DIM
from highway_srl.rules import OBS_NAMES, build_observation, observation_ranges
from highway_srl.rules.observation import ego_progress_feature
from highway_srl.sim.road import make_road


def obs(**over):
    base = dict(
        ego_progress=torch.tensor([1.0]), ego_y_local_m=torch.tensor([0.35]), ego_vx_mps=torch.tensor([8.0]),
        ego_vy_mps=torch.tensor([0.5]), ego_heading=torch.tensor([0.05]),
        sv_dx_m=torch.tensor([[25.0, 50.0, -10.0, -50.0]]), sv_y_local_m=torch.tensor([[0.0, 3.5, 0.0, 3.5]]),
        sv_vx_mps=torch.tensor([[5.0, 10.0, 6.0, 0.0]]), sv_vy_mps=torch.zeros(1, 4), sv_heading=torch.zeros(1, 4),
        c_id=torch.tensor([0]), m_l=torch.tensor([False]), t_id=torch.tensor([1]), v_star_mps=torch.tensor([10.0]),
        r_star=torch.tensor([[True, True, False, True]]), rm_state=torch.tensor([3]),
    )
    base.update(over)
    return build_observation(**base)


def test_observation_has_37_named_entries_in_paper_order():
    o = obs()
    assert o.shape == (1, OBS_DIM) == (1, 37) and len(OBS_NAMES) == 37
    d = dict(zip(OBS_NAMES, o[0].tolist()))
    assert d["ego_x"] == 1.0 and abs(d["ego_y"] - 0.1) < 1e-6 and abs(d["ego_vx"] - 0.8) < 1e-6
    assert d["sv1_x"] == 0.5 and d["sv2_x"] == 1.0 and abs(d["sv3_x"] + 0.2) < 1e-6 and d["sv2_y"] == 1.0
    assert d["t_id"] == 1.0 and d["v_star"] == 1.0 and d["r_sv3"] == 0.0
    assert [d[k] for k in ("u1", "u2", "u3", "u4")] == [0.0, 0.0, 0.0, 1.0]


def test_observation_is_finite_and_inside_documented_ranges_even_for_wild_inputs():
    o = obs(sv_dx_m=torch.tensor([[500.0, float("nan"), -1e9, 0.0]]), ego_heading=torch.tensor([7.0]),
            sv_vx_mps=torch.tensor([[40.0, float("inf"), -3.0, 0.0]]), ego_progress=torch.tensor([-9.0]))
    lo, hi = observation_ranges().unbind(1)
    assert torch.isfinite(o).all()
    assert ((o[0] >= lo - 1e-6) & (o[0] <= hi + 1e-6)).all()


def test_ego_progress_is_signed_distance_to_x2_over_100m():
    merge, exit_ = make_road("merge"), make_road("exit")
    assert ego_progress_feature(merge, torch.tensor([60.0, 160.0, 900.0])).tolist() == [1.0, 0.0, -3.0]
    assert ego_progress_feature(exit_, torch.tensor([exit_.zones["diverging"][1] - 50.0])).tolist() == [0.5]
    assert ego_progress_feature(make_road("two-lane"), torch.tensor([1234.0])).tolist() == [0.0]
