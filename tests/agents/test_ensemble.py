"""MLPEnsemble computes what M separate nn.Sequential MLPs compute."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from highway_srl.agents.ensemble import MLPEnsemble


def _separate_copies(ens: MLPEnsemble) -> list[nn.Sequential]:
    nets = []
    params = ens.params()
    for m in range(ens.num_members):
        layers = []
        for fan_in, fan_out in zip(ens.widths[:-1], ens.widths[1:]):
            layers += [nn.Linear(fan_in, fan_out), nn.ReLU()]
        net = nn.Sequential(*layers[:-1])  # no ReLU after the output layer
        with torch.no_grad():
            for lin, w, b in zip(net[0::2], params[0::2], params[1::2]):
                lin.weight.copy_(w[m].T)
                lin.bias.copy_(b[m, 0])
        nets.append(net)
    return nets


@pytest.mark.parametrize("hidden", [32, (16, 8, 12)], ids=["paper-shape", "three-hidden-layers"])
def test_ensemble_matches_separate_mlps_with_copied_weights(hidden):
    torch.manual_seed(0)
    ens = MLPEnsemble(5, 37, 4, hidden=hidden)
    nets = _separate_copies(ens)
    assert len(nets[0]) == 2 * len(ens.widths) - 3  # every layer, a ReLU between two
    x = torch.randn(7, 37)
    want = torch.stack([net(x) for net in nets])
    torch.testing.assert_close(ens(x), want)  # shared input (B, in) -> (M, B, out)
    xs = torch.randn(5, 7, 37)
    torch.testing.assert_close(ens(xs), torch.stack([net(xs[m]) for m, net in enumerate(nets)]))
    idx = torch.tensor([3, 0])
    torch.testing.assert_close(ens.forward_members(idx, xs[:2]), torch.stack([nets[3](xs[0]), nets[0](xs[1])]))


def test_forward_members_gradient_reaches_only_the_selected_members():
    torch.manual_seed(1)
    ens = MLPEnsemble(4, 6, 3, hidden=8)
    idx = torch.tensor([2])
    ens.forward_members(idx, torch.randn(1, 5, 6)).square().sum().backward()
    grad_norm = ens.flat.grad.abs().sum(1)
    assert grad_norm[2] > 0
    assert torch.count_nonzero(grad_norm).item() == 1


def test_init_is_nn_linear_uniform_and_independent_per_member():
    ens = MLPEnsemble(3, 37, 4, generator=torch.Generator().manual_seed(0))
    w1, b1, w2, b2, w3, b3 = ens.params()
    assert w1.shape == (3, 37, 256) and b1.shape == (3, 1, 256)
    assert w2.shape == (3, 256, 256) and w3.shape == (3, 256, 4) and b3.shape == (3, 1, 4)
    for w, b, fan_in in ((w1, b1, 37), (w2, b2, 256), (w3, b3, 256)):
        bound = 1 / math.sqrt(fan_in)
        assert w.abs().max() <= bound and b.abs().max() <= bound
        assert abs(w.std().item() - bound / math.sqrt(3)) < 0.1 * bound  # std of U(-c, c) is c/sqrt(3)
    assert not torch.equal(w2[0], w2[1])
    same = MLPEnsemble(3, 37, 4, generator=torch.Generator().manual_seed(0))
    assert torch.equal(same.flat, ens.flat)


def test_copy_from_and_state_dict_round_trip():
    a, b = MLPEnsemble(2, 5, 4, hidden=16), MLPEnsemble(2, 5, 4, hidden=16)
    x = torch.randn(3, 5)
    assert not torch.equal(a(x), b(x))
    b.copy_from(a)
    assert torch.equal(a(x), b(x))
    c = MLPEnsemble(2, 5, 4, hidden=16)
    state = a.state_dict()
    assert list(state) == ["flat"]
    c.load_state_dict(state)
    assert torch.equal(a(x), c(x))
