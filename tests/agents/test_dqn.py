"""DQNLearner: the TD update, per-member isolation, target syncs, and learning tiny tasks."""

from __future__ import annotations

import dataclasses

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from highway_srl.agents.dqn import DQNConfig, DQNLearner, UpdateLog, UpdateStats, td_loss_and_grad, td_target
from highway_srl.agents.ensemble import MLPEnsemble, ensemble_forward
from highway_srl.agents.gating import EXPERT_ACTION_SETS, expert_action_mask
from highway_srl.agents.replay import ExpertReplay

SMALL = DQNConfig(hidden=32, batch_size=16)


def _batch(mask: torch.Tensor, n: int, obs_dim: int, gen: torch.Generator, reward_scale: float = 1.0) -> dict:
    """A random batch (K, n, ...) whose actions lie inside each member's set (mask (K, out))."""
    k = mask.shape[0]
    return {
        "obs": torch.randn(k, n, obs_dim, generator=gen),
        "next_obs": torch.randn(k, n, obs_dim, generator=gen),
        "action": torch.multinomial(mask.float(), n, replacement=True, generator=gen),
        "reward": reward_scale * torch.randn(k, n, generator=gen),
        "done": torch.rand(k, n, generator=gen) < 0.2,
    }


def _state(learner: DQNLearner) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in learner.state_dict().items()}


def test_epsilon_decays_linearly_over_the_first_fifth_of_training():
    cfg = DQNConfig()
    assert (cfg.lr, cfg.gamma, cfg.batch_size, cfg.total_steps) == (1e-4, 0.99, 256, 500_000)
    assert cfg.epsilon(0) == 1.0
    assert cfg.epsilon(50_000) == pytest.approx(0.525)
    assert cfg.epsilon(100_000) == pytest.approx(0.05)
    assert cfg.epsilon(500_000) == pytest.approx(0.05)


def test_q_values_are_minus_infinity_outside_each_set_and_greedy_stays_inside():
    learner = DQNLearner(11, expert_action_mask(), SMALL, obs_dim=5, generator=torch.Generator().manual_seed(0))
    obs = torch.randn(64, 5)
    q = learner.q_values(obs)
    assert q.shape == (11, 64, 4)
    assert torch.equal(torch.isinf(q), ~expert_action_mask()[:, None, :].expand_as(q))
    greedy = learner.greedy(obs)
    assert greedy.shape == (64, 11)
    for e, actions in enumerate(EXPERT_ACTION_SETS):
        assert set(greedy[:, e].tolist()) <= set(actions)


def _q_and_target(learner: DQNLearner, idx: torch.Tensor, batch: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """Q(s, a) of the batch and Algorithm 1's target y = r + 0.99 (1 - done) max_a' Q_target(s', a'), (K, n) each."""
    with torch.no_grad():
        q_sa = learner.online.forward_members(idx, batch["obs"]).gather(2, batch["action"][..., None])[..., 0]
        q_next = learner.target.forward_members(idx, batch["next_obs"])
        q_next = q_next.masked_fill(~learner.action_mask[idx][:, None], -torch.inf).amax(-1)
        return q_sa, batch["reward"] + 0.99 * q_next * (~batch["done"])


def test_first_update_minimises_the_squared_td_error_of_algorithm_1_and_reports_its_q_and_td_error():
    gen = torch.Generator().manual_seed(0)
    learner = DQNLearner(3, expert_action_mask()[[0, 1, 5]], SMALL, obs_dim=5, generator=gen)
    idx = torch.tensor([2, 0])
    batch = _batch(learner.action_mask[idx], 32, 5, gen)
    q_sa, y = _q_and_target(learner, idx, batch)
    stats = learner.update(idx, batch)
    torch.testing.assert_close(stats.loss, (y - q_sa).square().mean(1))
    torch.testing.assert_close(stats.q_mean, q_sa.mean(1))
    torch.testing.assert_close(stats.td_error, (y - q_sa).abs().mean(1))
    assert learner.update(idx, batch).loss.sum() < stats.loss.sum()


def test_td_target_bootstraps_from_the_best_allowed_action():
    q_next = torch.tensor([[[1.0, 5.0, 3.0, 9.0], [2.0, 0.0, 4.0, 8.0]]])  # (K=1, N=2, 4)
    reward, done = torch.tensor([[1.0, 1.0]]), torch.tensor([[False, True]])
    allowed = torch.tensor([[True, True, True, False]])  # action 3 is outside the member's set
    assert torch.equal(td_target(q_next, reward, done, 0.5, allowed), torch.tensor([[3.5, 1.0]]))


def test_td_target_of_a_weighted_policy_bootstraps_every_member_of_a_group_from_its_one_choice():
    # LM-RL's pair (Q_r, Q_c) with λ = 2: scores Q_r - 2 Q_c = [1, -1, 3, -7] at the first s', so a' = 2
    # (not Q_r's max, 1), and [4, -4, -4, 0] at the second, a' = 0; both networks read Q_target(s', a').
    q_r = torch.tensor([[1.0, 5.0, 3.0, 9.0], [4.0, 0.0, 2.0, 8.0]])
    q_c = torch.tensor([[0.0, 3.0, 0.0, 8.0], [0.0, 2.0, 3.0, 4.0]])
    q_next = torch.stack([q_r, q_c])  # (K=2, N=2, 4)
    reward = torch.tensor([[1.0, 1.0], [0.0, 10.0]])  # the cost network's reward is the cost
    done = torch.tensor([[False, False], [False, False]])
    allowed = torch.ones(2, 4, dtype=torch.bool)
    y = td_target(q_next, reward, done, 0.5, allowed, next_weight=torch.tensor([[1.0, -2.0]]))
    assert torch.equal(y, torch.tensor([[1.0 + 0.5 * 3.0, 1.0 + 0.5 * 4.0], [0.0 + 0.5 * 0.0, 10.0 + 0.5 * 0.0]]))
    # weights (1, 0): the reward network's own max, the DQN target
    dqn = td_target(q_next, reward, done, 0.5, allowed, next_weight=torch.tensor([[1.0, 0.0]]))
    assert torch.equal(dqn[0], td_target(q_next[:1], reward[:1], done[:1], 0.5, allowed[:1])[0])


def test_update_log_averages_over_member_updates_and_has_nothing_before_the_first():
    stats = UpdateStats(torch.tensor([1.0, 3.0]), torch.tensor([10.0, 20.0]), torch.tensor([0.5, 1.5]))
    log = UpdateLog("cpu")
    assert log.read() == {}
    log.add(stats)
    log.add(stats.rows(slice(0, 1)))
    assert log.read() == pytest.approx({"loss": 5.0 / 3, "q_mean": 40.0 / 3, "td_error": 2.5 / 3})
    assert log.read() == {}  # a read starts again


def test_masked_adam_equals_torch_adam_with_clipping_on_one_member():
    gen = torch.Generator().manual_seed(0)
    learner = DQNLearner(3, torch.ones(3, 4, dtype=torch.bool), SMALL, obs_dim=5, generator=gen)
    w1, b1, w2, b2, w3, b3 = learner.online.params()
    net = nn.Sequential(nn.Linear(5, 32), nn.ReLU(), nn.Linear(32, 32), nn.ReLU(), nn.Linear(32, 4))
    target = nn.Sequential(nn.Linear(5, 32), nn.ReLU(), nn.Linear(32, 32), nn.ReLU(), nn.Linear(32, 4))
    with torch.no_grad():
        for mod in (net, target):
            for lin, w, b in zip((mod[0], mod[2], mod[4]), (w1, w2, w3), (b1, b2, b3)):
                lin.weight.copy_(w[1].T)
                lin.bias.copy_(b[1, 0])
    opt = torch.optim.Adam(net.parameters(), lr=SMALL.lr, betas=SMALL.adam_betas, eps=SMALL.adam_eps)
    norms = []
    for step in range(6):
        batch = _batch(learner.action_mask[[1]], 16, 5, gen, reward_scale=100.0 if step % 2 else 0.1)
        learner.update(torch.tensor([1]), batch)
        with torch.no_grad():
            y = batch["reward"][0] + 0.99 * (~batch["done"][0]) * target(batch["next_obs"][0]).amax(-1)
        q_sa = net(batch["obs"][0]).gather(1, batch["action"][0][:, None])[:, 0]
        opt.zero_grad()
        (q_sa - y).square().mean().backward()
        norms.append(nn.utils.clip_grad_norm_(net.parameters(), SMALL.grad_clip_norm).item())
        opt.step()
    assert min(norms) < SMALL.grad_clip_norm < max(norms)  # both branches of the clipping ran
    w1, b1, w2, b2, w3, b3 = learner.online.params()
    for lin, w, b in zip((net[0], net[2], net[4]), (w1, w2, w3), (b1, b2, b3)):
        torch.testing.assert_close(w[1].T, lin.weight, rtol=1e-5, atol=1e-7)
        torch.testing.assert_close(b[1, 0], lin.bias, rtol=1e-5, atol=1e-7)


def test_updating_some_members_leaves_every_other_member_bit_identical():
    gen = torch.Generator().manual_seed(0)
    learner = DQNLearner(5, expert_action_mask()[[0, 2, 4, 6, 8]], SMALL, obs_dim=5, generator=gen)
    for idx in ([0, 1, 2, 3, 4], [1, 3]):  # everyone gets Adam moments first
        learner.update(torch.tensor(idx), _batch(learner.action_mask[idx], 16, 5, gen))
    before = _state(learner)
    for _ in range(3):
        learner.update(torch.tensor([3, 0]), _batch(learner.action_mask[[3, 0]], 16, 5, gen))
    after = learner.state_dict()
    for key in ("online.flat", "target.flat", "adam.exp_avg", "adam.exp_avg_sq", "adam.step", "target_update_count"):
        for m in (1, 2, 4):
            assert torch.equal(before[key][m], after[key][m]), (key, m)
        for m in (0, 3):
            if key in ("online.flat", "adam.exp_avg", "adam.exp_avg_sq", "adam.step"):
                assert not torch.equal(before[key][m], after[key][m]), (key, m)
    assert after["adam.step"].tolist() == [4, 2, 1, 5, 1]


def test_in_place_rows_step_bit_for_bit_as_the_gathered_form_with_target_syncs_and_several_members():
    """The CPU's update steps the members' rows in place (DQNLearner.rows_in_place); it must be the gathered
    form's step exactly, for one member (the target read as a view) and several, across target syncs."""
    config = dataclasses.replace(SMALL, target_update_interval=2)

    def run(in_place: bool) -> dict[str, torch.Tensor]:
        gen = torch.Generator().manual_seed(5)
        learner = DQNLearner(6, expert_action_mask()[[0, 2, 4, 6, 8, 10]], config, obs_dim=5,
                             generator=torch.Generator().manual_seed(1))
        learner.rows_in_place = in_place
        for members in ([2], [2], [0, 4, 5], [2], [5, 1], [2], [3], [0, 1, 2, 3, 4, 5], [2], [4]):
            learner.update(torch.tensor(members), _batch(learner.action_mask[members], 16, 5, gen))
        return _state(learner)

    assert DQNLearner(1, torch.ones(1, 4, dtype=torch.bool), SMALL).rows_in_place  # the CPU's default
    in_place, gathered = run(True), run(False)
    assert gathered["target_update_count"].tolist() != [0] * 6 and int(gathered["adam.step"][2]) == 6
    assert not torch.equal(gathered["target.flat"][2], DQNLearner(6, expert_action_mask()[[0, 2, 4, 6, 8, 10]],
                           config, obs_dim=5, generator=torch.Generator().manual_seed(1)).target.flat[2])
    for key in gathered:
        assert torch.equal(in_place[key], gathered[key]), key


@pytest.mark.parametrize("in_place", [True, False], ids=["rows-in-place", "gathered"])
def test_without_torchs_fused_adam_the_update_steps_as_the_fused_kernel_does(in_place, monkeypatch):
    """The fused Adam kernel is a private torch op; a learner made where it is missing steps its rows through
    public operations, to float rounding the same as the kernel, across a target sync and with clipping."""
    config = dataclasses.replace(SMALL, target_update_interval=2, grad_clip_norm=0.5)

    def make() -> DQNLearner:
        return DQNLearner(4, expert_action_mask()[[0, 2, 4, 6]], config, obs_dim=5,
                          generator=torch.Generator().manual_seed(1))

    def run() -> tuple[DQNLearner, dict[str, torch.Tensor]]:
        gen = torch.Generator().manual_seed(3)
        learner = make()
        learner.rows_in_place = in_place
        for members in ([1], [0, 3], [1, 2], [1], [0, 1, 2, 3]):
            learner.update(torch.tensor(members), _batch(learner.action_mask[members], 16, 5, gen))
        return learner, _state(learner)

    fused, want = run()
    assert fused.fused_adam is not None  # this torch has the kernel: the comparison below means something
    monkeypatch.delattr(torch, "_fused_adam_")
    fallback, got = run()
    assert fallback.fused_adam is None
    assert got["adam.step"].tolist() == [2, 4, 2, 2]
    for key in ("online.flat", "target.flat", "adam.exp_avg", "adam.exp_avg_sq"):
        torch.testing.assert_close(got[key], want[key], rtol=1e-5, atol=1e-6)
    assert not torch.equal(got["online.flat"], make().online.flat)


@pytest.mark.parametrize("hidden", [32, (16, 8, 12)], ids=["paper-shape", "three-hidden-layers"])
@pytest.mark.parametrize("huber", [False, True])
def test_written_out_gradient_is_the_autograd_gradient_of_the_summed_member_losses(huber, hidden):
    gen = torch.Generator().manual_seed(3)
    net = MLPEnsemble(3, 5, 4, hidden, generator=gen)
    batch = _batch(expert_action_mask()[[0, 5, 9]], 16, 5, gen)
    y = 3.0 * torch.randn(3, 16, generator=gen)  # large errors: Huber's clipped branch runs too
    theta = net.flat.detach().clone().requires_grad_()
    q = ensemble_forward(net.unflatten(theta), batch["obs"])
    q_sa = q.gather(2, batch["action"].unsqueeze(2)).squeeze(2)
    loss = F.smooth_l1_loss(q_sa, y, reduction="none").mean(1) if huber else (q_sa - y).square().mean(1)
    (want,) = torch.autograd.grad(loss.sum(), theta)
    got_q, got_loss, got = td_loss_and_grad(net, theta.detach(), batch["obs"], batch["action"], y, huber)
    torch.testing.assert_close(got_q, q_sa.detach())
    torch.testing.assert_close(got_loss, loss.detach())
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-7)


def test_masked_update_steps_the_masked_in_members_as_update_does_and_leaves_the_others_unchanged():
    gen = torch.Generator().manual_seed(4)
    cfg = dataclasses.replace(SMALL, target_update_interval=2)  # a target sync happens within the 3 updates
    make = lambda: DQNLearner(4, expert_action_mask()[[0, 1, 5, 7]], cfg, obs_dim=5,  # noqa: E731
                              generator=torch.Generator().manual_seed(0))
    compact, masked = make(), make()
    every = torch.arange(4)
    mask = torch.tensor([True, False, True, False])
    for _ in range(3):
        batch = _batch(compact.action_mask, 16, 5, gen)
        before = _state(masked)
        compact.update(torch.tensor([0, 2]), {k: v[[0, 2]] for k, v in batch.items()})
        stats = masked.update_masked(every, batch, mask)
        after = masked.state_dict()
        for key in ("online.flat", "target.flat", "adam.exp_avg", "adam.exp_avg_sq", "adam.step", "target_update_count"):
            assert torch.equal(before[key][[1, 3]], after[key][[1, 3]]), key
            torch.testing.assert_close(after[key][[0, 2]], compact.state_dict()[key][[0, 2]], rtol=1e-5, atol=1e-6)
        assert stats.loss.shape == (4,)
    # the 3rd update takes the counter past 2: the target takes the online weights, for the updated members only
    assert torch.equal(masked.target.flat[[0, 2]], masked.online.flat[[0, 2]])
    assert not torch.equal(masked.target.flat[[0, 2]], make().target.flat[[0, 2]])


def test_target_network_takes_the_online_weights_when_the_member_counter_exceeds_the_interval():
    cfg = dataclasses.replace(SMALL, target_update_interval=3)
    gen = torch.Generator().manual_seed(0)
    learner = DQNLearner(2, torch.ones(2, 4, dtype=torch.bool), cfg, obs_dim=5, generator=gen)
    initial = learner.target.flat.detach().clone()
    for n in range(1, 4):
        learner.update(torch.tensor([0]), _batch(learner.action_mask[[0]], 16, 5, gen))
        assert learner.target_update_count.tolist() == [n, 0]
        assert torch.equal(learner.target.flat, initial)
    learner.update(torch.tensor([0]), _batch(learner.action_mask[[0]], 16, 5, gen))  # n = 4 > n_t = 3
    assert learner.target_update_count.tolist() == [0, 0]
    assert torch.equal(learner.target.flat[0], learner.online.flat[0])
    assert torch.equal(learner.target.flat[1], initial[1])


def test_outputs_outside_a_members_set_never_change():
    gen = torch.Generator().manual_seed(0)
    mask = expert_action_mask()
    learner = DQNLearner(11, mask, SMALL, obs_dim=5, generator=gen)
    w3_before, b3_before = (t.clone() for t in learner.online.params()[4:])
    for _ in range(5):
        learner.update(torch.arange(11), _batch(mask, 16, 5, gen, reward_scale=10.0))
    w3, b3 = learner.online.params()[4:]
    unused = ~mask
    assert torch.equal(w3.transpose(1, 2)[unused], w3_before.transpose(1, 2)[unused])
    assert torch.equal(b3[:, 0][unused], b3_before[:, 0][unused])
    assert not torch.equal(w3.transpose(1, 2)[mask], w3_before.transpose(1, 2)[mask])


def test_state_dict_round_trip_gives_identical_q_values_and_identical_next_updates():
    gen = torch.Generator().manual_seed(0)
    mask = expert_action_mask()[[0, 3, 7]]
    a = DQNLearner(3, mask, SMALL, obs_dim=5, generator=gen)
    for _ in range(4):
        a.update(torch.tensor([0, 2]), _batch(mask[[0, 2]], 16, 5, gen))
    b = DQNLearner(3, mask, SMALL, obs_dim=5, generator=torch.Generator().manual_seed(99))
    b.load_state_dict(_state(a))
    obs = torch.randn(10, 5)
    assert torch.equal(a.q_values(obs), b.q_values(obs))
    batch = _batch(mask[[1, 2]], 16, 5, gen)
    assert torch.equal(a.update(torch.tensor([1, 2]), batch).loss, b.update(torch.tensor([1, 2]), batch).loss)
    for key, value in a.state_dict().items():
        assert torch.equal(value, b.state_dict()[key]), key
    with pytest.raises(ValueError, match="action sets"):
        DQNLearner(3, expert_action_mask()[[0, 3, 8]], SMALL, obs_dim=5).load_state_dict(a.state_dict())


def test_learns_the_best_action_inside_each_members_set_on_a_contextual_bandit():
    # 6 contexts, rewards spaced 0.2 apart; every member must find the best action of its own set.
    gen = torch.Generator().manual_seed(0)
    cfg = dataclasses.replace(SMALL, lr=1e-3, batch_size=64)
    members = [0, 1, 5, 8]  # sets {F,I,S,L}, {I,S,L}, {F,S}, {S,L}
    mask = expert_action_mask()[members]
    learner = DQNLearner(len(members), mask, cfg, obs_dim=6, generator=gen)
    reward_table = torch.stack([torch.randperm(4, generator=gen).float() * 0.2 for _ in range(6)])  # (6, 4)
    for _ in range(600):
        ctx = torch.randint(0, 6, (len(members), 64), generator=gen)
        action = torch.multinomial(mask.float(), 64, replacement=True, generator=gen)
        obs = nn.functional.one_hot(ctx, 6).float()
        batch = {"obs": obs, "next_obs": obs, "action": action, "reward": reward_table[ctx, action],
                 "done": torch.ones(len(members), 64, dtype=torch.bool)}  # fmt: skip
        learner.update(torch.arange(len(members)), batch)
    greedy = learner.greedy(torch.eye(6))  # (6 contexts, members)
    best = reward_table[:, None, :].masked_fill(~mask[None], -1).argmax(-1)
    assert torch.equal(greedy, best)


@pytest.mark.slow
def test_learns_a_chain_mdp_that_needs_bootstrapping():
    # States 0..4 (one-hot). The right action in state s is s % 4: it moves on with reward 0, and
    # from state 4 ends the episode with reward 1. Every other action ends it at once with 0.5. A
    # learner that ignores the future takes 0.5; Q*(s, right) = 0.99^(4 - s) > 0.5 requires the
    # TD target through the target network.
    gen = torch.Generator().manual_seed(0)
    cfg = dataclasses.replace(SMALL, lr=1e-3, batch_size=64, target_update_interval=50)
    learner = DQNLearner(1, torch.ones(1, 4, dtype=torch.bool), cfg, obs_dim=5, generator=gen)
    replay = ExpertReplay(1, 5, capacity=64)
    s, a = torch.arange(5).repeat_interleave(4), torch.arange(4).repeat(5)
    right = a == s % 4
    next_s = torch.where(right & (s < 4), s + 1, s)
    reward = torch.where(right, (s == 4).float(), torch.tensor(0.5))
    done = ~right | (s == 4)
    eye = torch.eye(5)
    replay.add(torch.zeros(20, dtype=torch.long), eye[s], a, reward, eye[next_s], done)
    for _ in range(1500):
        learner.update(torch.tensor([0]), replay.sample(torch.tensor([0]), 64, gen))
    assert learner.greedy(eye)[:, 0].tolist() == [0, 1, 2, 3, 0]
    q_right = learner.q_values(eye)[0, torch.arange(5), torch.arange(5) % 4]
    torch.testing.assert_close(q_right, 0.99 ** (4 - torch.arange(5.0)), atol=0.05, rtol=0)
