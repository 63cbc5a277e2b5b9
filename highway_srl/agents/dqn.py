"""DQN for a stack of experts (Algorithm 1, the DQN target and loss of §2.3).

Each member m has its own online and target network, its own action set A_m (a row of
`action_mask`), its own Adam state and its own target-update counter. `update` trains any
subset of members in one batched pass, at a cost proportional to the subset's size.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from highway_srl.agents.ensemble import MLPEnsemble, layer_outputs
from highway_srl.constants import BATCH_SIZE, GAMMA, LEARNING_RATE, OBS_DIM, TOTAL_STEPS


@dataclass
class DQNConfig:
    """Table 2 values, plus the choices the paper leaves open (see docs/paper-notes.md)."""

    lr: float = LEARNING_RATE  # Table 2
    gamma: float = GAMMA  # Table 2
    batch_size: int = BATCH_SIZE  # Table 2, per member update
    total_steps: int = TOTAL_STEPS  # Table 2, environment steps
    hidden: int = 256  # §4.1
    buffer_capacity: int = 100_000  # per member; not in the paper
    learning_starts: int = 1000  # environment steps collected before the first update
    target_update_interval: int = 500  # n_t, counted in the member's own updates (n_i,j)
    eps_start: float = 1.0
    eps_end: float = 0.05
    exploration_fraction: float = 0.2  # epsilon decays linearly over this share of total_steps
    grad_clip_norm: float = 10.0  # per member, over all its parameters; <= 0 disables
    huber: bool = False  # False: the paper's squared TD error; True: Huber (smooth L1, beta 1)
    adam_betas: tuple[float, float] = (0.9, 0.999)
    adam_eps: float = 1e-8

    def epsilon(self, step: int) -> float:
        """Exploration probability at environment step `step` (linear, then flat)."""
        span = max(1.0, self.exploration_fraction * self.total_steps)
        frac = min(1.0, step / span)
        return self.eps_start + frac * (self.eps_end - self.eps_start)


@dataclass
class UpdateStats:
    """What one update measured, (K,) per updated member, detached on the learner's device."""

    loss: torch.Tensor  # the minimised loss: mean squared TD error (or Huber)
    q_mean: torch.Tensor  # mean Q_m(s, a) over the batch
    td_error: torch.Tensor  # mean |y - Q_m(s, a)| over the batch

    def rows(self, which: slice) -> "UpdateStats":
        """The stats of the updated members which selects (LM-RL: every other one, its reward networks)."""
        return UpdateStats(self.loss[which], self.q_mean[which], self.td_error[which])


class UpdateLog:
    """Sums of UpdateStats over member updates since the last read, kept on the device: add() only queues
    work (no host read per update); read() makes the one host read at log time and starts again."""

    FIELDS = ("loss", "q_mean", "td_error")

    def __init__(self, device: torch.device | str):
        self.sums = torch.zeros(len(self.FIELDS), device=device)
        self.count = torch.zeros((), dtype=torch.long, device=device)  # member updates summed (on the device)

    def add(self, stats: UpdateStats | None, mask: torch.Tensor | None = None) -> None:
        """mask (K,) bool: only these members were updated (the masked form); None: all of them."""
        if stats is None:
            return
        values = torch.stack([stats.loss, stats.q_mean, stats.td_error])  # (3, K)
        if mask is None:
            self.sums += values.sum(1)
            self.count += stats.loss.shape[0]
        else:
            self.sums += torch.where(mask, values, 0.0).sum(1)
            self.count += mask.long().sum()

    def read(self) -> dict[str, float]:
        """Mean loss, Q and |TD error| per member update since the last read; {} if there was none."""
        count = int(self.count)
        if count == 0:
            return {}
        means = (self.sums / count).tolist()
        self.sums.zero_()
        self.count.zero_()
        return dict(zip(self.FIELDS, means))


def td_target(q_next: torch.Tensor, reward: torch.Tensor, done: torch.Tensor, gamma: float,
              allowed: torch.Tensor, next_weight: torch.Tensor | None = None) -> torch.Tensor:
    """The TD target of every update, (K, N): y = r + gamma (1 - done) Q_target,m(s', a').

    q_next (K, N, out) the target networks' Q-values at s'; reward (K, N); done (K, N) bool (termination only).
    a' is the max over the member's own actions, allowed (K, out) bool (Algorithm 1). A method whose policy
    scores actions with several networks (LM-RL: Q_r - λ Q_c) names next_weight (G, S): the K = G S members
    form G groups of S consecutive members, and each group bootstraps from one a' = argmax over the group's
    first member's allowed actions of sum_s next_weight[g, s] Q_target,s(s', a), the policy's own choice
    read from the same target networks (with weights (1, 0, ...) the first member's max)."""
    if next_weight is not None:
        groups, size = next_weight.shape
        score = (q_next.unflatten(0, (groups, size)) * next_weight[:, :, None, None]).sum(1)  # (G, N, out)
        score = score.masked_fill(~allowed[::size].unsqueeze(1), float("-inf"))
        next_action = score.argmax(-1).repeat_interleave(size, 0)  # (K, N)
        value = q_next.gather(2, next_action.unsqueeze(2)).squeeze(2)
    else:
        value = q_next.masked_fill(~allowed.unsqueeze(1), float("-inf")).amax(-1)
    return reward + gamma * (~done).to(value.dtype) * value


def td_loss_and_grad(net: MLPEnsemble, theta: torch.Tensor, obs: torch.Tensor, action: torch.Tensor,
                     y: torch.Tensor, huber: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The DQN loss of K members and its gradient, written out (no autograd: one graph for torch.compile).

    theta (K, P) the members' flat weights; obs (K, N, in); action (K, N) long; y (K, N) the TD targets.
    Returns q_sa (K, N), the per-member mean loss (K,) and d(sum of the per-member losses)/d theta (K, P):
    the same gradient autograd gives (tests/agents/test_dqn.py), through the layers of net.widths."""
    params = net.unflatten(theta)
    outputs = layer_outputs(params, obs)  # [obs, h1, ..., q]
    q = outputs[-1]
    q_sa = q.gather(2, action.unsqueeze(2)).squeeze(2)
    diff = q_sa - y
    n = diff.shape[1]
    if huber:
        per_member = F.smooth_l1_loss(q_sa, y, reduction="none").mean(1)
        d_q_sa = diff.clamp(-1.0, 1.0) / n
    else:
        per_member = diff.square().mean(1)
        d_q_sa = diff * (2.0 / n)
    d_out = torch.zeros_like(q).scatter_(2, action.unsqueeze(2), d_q_sa.unsqueeze(2))  # (K, N, out)
    grads = []
    for i in range(len(params) // 2 - 1, -1, -1):  # layer i maps outputs[i] to outputs[i + 1]
        grads[:0] = [torch.bmm(outputs[i].transpose(1, 2), d_out), d_out.sum(1, keepdim=True)]
        if i > 0:
            # ReLU's backward as autograd computes it (ReluBackward): one pass, where a product with the (h > 0)
            # mask converts the mask to floats first (about 8x the time on a 256 x 256 batch, scripts/cpu_ops.py)
            d_out = torch.ops.aten.threshold_backward(torch.bmm(d_out, params[2 * i].transpose(1, 2)), outputs[i], 0.0)
    grad = torch.cat([g.reshape(g.shape[0], -1) for g in grads], 1)
    return q_sa, per_member, grad


class DQNLearner:
    """Online/target `MLPEnsemble`s with masked Q-values and a per-member Adam.

    action_mask: (M, out_dim) bool, true on each member's actions. All state lives on `device`;
    generator (CPU) seeds the initial weights, which the target network copies.
    """

    def __init__(
        self,
        num_members: int,
        action_mask: torch.Tensor,
        config: DQNConfig | None = None,
        device: torch.device | str | None = None,
        obs_dim: int = OBS_DIM,
        out_dim: int = 4,
        generator: torch.Generator | None = None,
    ) -> None:
        self.config = config if config is not None else DQNConfig()
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        if tuple(action_mask.shape) != (num_members, out_dim):
            raise ValueError(f"action_mask has shape {tuple(action_mask.shape)}, expected {(num_members, out_dim)}")
        self.num_members, self.obs_dim, self.out_dim = num_members, obs_dim, out_dim
        self.action_mask = action_mask.to(self.device, torch.bool)
        hidden = self.config.hidden
        self.online = MLPEnsemble(num_members, obs_dim, out_dim, hidden, self.device, generator)
        self.target = MLPEnsemble(num_members, obs_dim, out_dim, hidden, self.device)
        self.target.copy_from(self.online)
        self.target.requires_grad_(False)
        # torch.optim.Adam keeps moving a parameter whose gradient is zero (its first moment
        # is still non-zero from earlier steps) and has one step count for the whole tensor,
        # which would drive every member's bias correction by the others' updates. Experts are
        # trained independently (§3.4), so each member gets its own moments and step count,
        # and a step touches only the members being updated.
        self.exp_avg = torch.zeros_like(self.online.flat, requires_grad=False)  # (M, P)
        self.exp_avg_sq = torch.zeros_like(self.online.flat, requires_grad=False)
        self.adam_step = torch.zeros(num_members, device=self.device)
        self.target_update_count = torch.zeros(num_members, dtype=torch.long, device=self.device)  # n_i,j
        # `update` on the CPU reads the members' indices on the host (free there) and steps their rows in
        # place: no gathered copies of the moments and weights written back, and the target copied only
        # when it syncs (an index_copy_ of one member's row costs 35-44 us: `python scripts/cpu_ops.py
        # costs`, docs/benchmarks.md). Same operations on the same values, so bit for bit the gathered form,
        # which stays for devices where a host read waits for the queue (tests/agents/test_dqn.py compares).
        self.rows_in_place = self.device.type == "cpu"
        # torch's fused Adam kernel is a private op: where a torch build lacks it, the compact update steps
        # its rows with the elementwise form through public operations (_adam_rows), to float rounding the same
        self.fused_adam = getattr(torch, "_fused_adam_", None)

    @torch.no_grad()
    def q_values(self, obs: torch.Tensor) -> torch.Tensor:
        """obs: (B, obs_dim) -> (M, B, out_dim); actions outside a member's set are -inf."""
        q = self.online(obs.to(self.device))
        return q.masked_fill(~self.action_mask.unsqueeze(1), float("-inf"))

    @torch.no_grad()
    def greedy(self, obs: torch.Tensor) -> torch.Tensor:
        """obs: (B, obs_dim) -> (B, M) long: each member's argmax over its own action set."""
        return self.q_values(obs).argmax(-1).T

    def update(self, members: torch.Tensor, batch: dict[str, torch.Tensor]) -> UpdateStats:
        """One gradient step for each of `members` (K,) long (distinct indices) on its own batch.

        batch: "obs" (K, N, obs_dim), "action" (K, N) long (inside the member's set),
        "reward" (K, N), "next_obs" (K, N, obs_dim), "done" (K, N) bool (termination only).
        TD target y = r + gamma (1 - done) max_{a' in A_m} Q_target,m(s', a') (Algorithm 1, `td_target`); a
        method whose policy combines several networks (LM-RL) names their weights as "next_weight" (G, S), and
        a' is that policy's choice instead of each member's max.
        loss = mean over N of (y - Q_m(s, a))^2 (the DQN loss of §2.3), or Huber if configured.
        Returns the per-member loss, mean Q(s, a) and mean |TD error| (UpdateStats, (K,) each), detached.
        Nothing here reads a value back to the host, so on a GPU the call queues work without synchronising.
        """
        cfg = self.config
        idx = members.to(self.device)
        obs, action = batch["obs"].to(self.device), batch["action"].to(self.device)
        rows = idx.tolist() if self.rows_in_place else None
        with torch.no_grad():
            old_target = self._rows_of(self.target, idx, rows)
            y = self._td_target(idx, old_target, {k: v.to(self.device) for k, v in batch.items()})
            # the gradient written out (the same as autograd's: tests/agents/test_dqn.py), without the
            # autograd engine's bookkeeping and its final concatenation of the layers' gradients
            theta = self._rows_of(self.online, idx, rows)
            q_sa, per_member, grad = td_loss_and_grad(self.online, theta, obs, action, y, cfg.huber)
            if rows is None:  # gathered rows stepped, then written back
                m, v = self.exp_avg.index_select(0, idx), self.exp_avg_sq.index_select(0, idx)
                self._adam_rows(idx, grad, theta.unbind(0), m.unbind(0), v.unbind(0))
                self.online.flat.index_copy_(0, idx, theta)
                self.exp_avg.index_copy_(0, idx, m)
                self.exp_avg_sq.index_copy_(0, idx, v)
            else:  # the members' rows stepped in place
                flat = self.online.flat.detach()
                self._adam_rows(idx, grad, [flat[i] for i in rows], [self.exp_avg[i] for i in rows],
                                 [self.exp_avg_sq[i] for i in rows])
            # Algorithm 1: n_i,j counts the member's updates; when it exceeds n_t the target
            # takes the online weights and the counter restarts.
            count = self.target_update_count[idx] + 1
            sync = count > cfg.target_update_interval
            self.target_update_count.index_copy_(0, idx, torch.where(sync, torch.zeros_like(count), count))
            if rows is None:
                self.target.flat.index_copy_(0, idx, torch.where(sync.unsqueeze(1), theta, old_target))
            else:
                for k in sync.nonzero().flatten().tolist():
                    self.target.flat[rows[k]].copy_(self.online.flat[rows[k]])
        return UpdateStats(per_member, q_sa.mean(1), (y - q_sa).abs().mean(1))

    @torch.no_grad()
    def update_masked(self, members: torch.Tensor, batch: dict[str, torch.Tensor], mask: torch.Tensor) -> UpdateStats:
        """The static form of `update`: one gradient step for each of `members` (K,) long (distinct) where
        mask (K,) bool is True; the others are computed alongside but keep their weights, target, Adam
        moments and counters. No host read and no shape that depends on the data, so that a fixed set of
        members (all of them) updates as one graph (torch.compile, CUDA graphs); the gradient is written
        out (td_loss_and_grad). The same step as `update` for the masked-in members, to float rounding."""
        cfg = self.config
        idx = members.to(self.device)
        obs, action = batch["obs"], batch["action"]
        old_target = self.target.gather(idx)  # (K, P)
        y = self._td_target(idx, old_target, batch)
        theta = self.online.flat.index_select(0, idx)
        q_sa, per_member, grad = td_loss_and_grad(self.online, theta, obs, action, y, cfg.huber)
        new_theta = self._adam_step(idx, theta, grad, mask)
        self.online.flat.index_copy_(0, idx, new_theta)
        count = self.target_update_count[idx] + mask.long()
        sync = mask & (count > cfg.target_update_interval)
        self.target_update_count.index_copy_(0, idx, torch.where(sync, torch.zeros_like(count), count))
        self.target.flat.index_copy_(0, idx, torch.where(sync.unsqueeze(1), new_theta, old_target))
        return UpdateStats(per_member, q_sa.mean(1), (y - q_sa).abs().mean(1))

    @staticmethod
    def _rows_of(net: MLPEnsemble, idx: torch.Tensor, rows: list[int] | None) -> torch.Tensor:
        """The rows (K, P) of net's members idx (K,): a view of net.flat where their host indices rows are
        consecutive and ascending (one member, or LM-RL's reward and cost networks), else a gathered copy: the
        same values either way (LM-RL's copies of its two rows, 0.6 MB each a round, were 9% of its training
        step's time under torch.profiler)."""
        if rows and rows == list(range(rows[0], rows[0] + len(rows))):
            return net.flat[rows[0]:rows[0] + len(rows)]
        return net.gather(idx)

    def _td_target(self, idx: torch.Tensor, target_rows: torch.Tensor, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """td_target of members idx (K,) on batch, from their target networks' rows target_rows (K, P)."""
        q_next = self.target.forward_rows(target_rows, batch["next_obs"])
        return td_target(q_next, batch["reward"], batch["done"], self.config.gamma, self.action_mask[idx],
                         batch.get("next_weight"))

    def _adam_step(self, idx: torch.Tensor, theta: torch.Tensor, grad: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The static update's Adam with per-member gradient-norm clipping on gathered rows theta, grad (K, P),
        written elementwise (a compiler fuses it; the compact update runs torch's fused kernel: _adam_rows).

        Only the members idx where mask (K,) is True step: their moments and step counts are updated and their
        new weights returned (K, P); the others keep their moments, count and weights.
        """
        grad = self._clipped(grad)
        old_step = self.adam_step[idx]
        step = old_step + 1
        self.adam_step.index_copy_(0, idx, torch.where(mask, step, old_step))
        step_size, bias2_sqrt = self._bias_corrections(step)
        m, v = self._adam_moments(self.exp_avg.index_select(0, idx), self.exp_avg_sq.index_select(0, idx), grad)
        rows = mask.unsqueeze(1)
        self.exp_avg.index_copy_(0, idx, torch.where(rows, m, self.exp_avg.index_select(0, idx)))
        self.exp_avg_sq.index_copy_(0, idx, torch.where(rows, v, self.exp_avg_sq.index_select(0, idx)))
        denom = self._adam_denom(v, step_size, bias2_sqrt)
        return torch.where(rows, theta.addcdiv(m, denom, value=-1.0), theta)

    def _adam_rows(self, idx: torch.Tensor, grad: torch.Tensor, params, exp_avgs, exp_avg_sqs) -> None:
        """The compact update's Adam with per-member gradient-norm clipping: members idx (K,), their
        gradients grad (K, P), and their weight, first- and second-moment rows (K tensors (P,) each, stepped
        in place). torch's fused Adam kernel (what torch.optim.Adam(fused=True) runs): one pass over a row
        where the elementwise form (_adam_step) takes eight, each through memory, since a member's rows
        (1.2 MB) and the batch's activations do not stay in a 2 MB cache (docs/log/benchmarks-history.md, session 14).
        Without the kernel (fused_adam None) the rows step by the elementwise form. Either is the same step
        as _adam_step to float rounding (tests/agents/test_dqn.py); the clipping's factor enters as the
        kernel's gradient divisor."""
        cfg = self.config
        beta1, beta2 = cfg.adam_betas
        step = self.adam_step[idx] + 1
        self.adam_step.index_copy_(0, idx, step)
        if self.fused_adam is None:
            grad = self._clipped(grad)
            step_size, bias2_sqrt = self._bias_corrections(step)
            for k, (theta, m, v) in enumerate(zip(params, exp_avgs, exp_avg_sqs)):
                self._adam_moments(m, v, grad[k])
                theta.addcdiv_(m, self._adam_denom(v, step_size[k], bias2_sqrt[k]), value=-1.0)
            return
        divisor = self._clip_divisor(grad)
        for k in range(len(params)):
            # the public torch.optim.adam.adam(fused=True) would regroup the tensors and add the step count on
            # every call (tens of us); the kernel itself takes the count as given
            self.fused_adam([params[k]], [grad[k]], [exp_avgs[k]], [exp_avg_sqs[k]], [], [step[k]],
                            lr=cfg.lr, beta1=beta1, beta2=beta2, weight_decay=0.0, eps=cfg.adam_eps,
                            amsgrad=False, maximize=False, grad_scale=None if divisor is None else divisor[k])

    def _adam_moments(self, m: torch.Tensor, v: torch.Tensor, grad: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Adam's moments m, v moved toward grad, in place (and returned)."""
        beta1, beta2 = self.config.adam_betas
        return m.lerp_(grad, 1 - beta1), v.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)

    def _adam_denom(self, v: torch.Tensor, step_size: torch.Tensor, bias2_sqrt: torch.Tensor) -> torch.Tensor:
        """What m is divided by in Adam's step theta - m / denom: (sqrt(v / (1 - beta2^t)) + eps) (1 - beta1^t) / lr,
        as torch.optim.Adam, with step_size, bias2_sqrt from _bias_corrections."""
        return v.sqrt().div_(bias2_sqrt).add_(self.config.adam_eps).div_(step_size)

    def _clipped(self, grad: torch.Tensor) -> torch.Tensor:
        """grad (K, P) scaled so that each member's norm is at most grad_clip_norm (<= 0: unchanged)."""
        divisor = self._clip_divisor(grad)
        return grad if divisor is None else grad / divisor.unsqueeze(1)

    def _clip_divisor(self, grad: torch.Tensor) -> torch.Tensor | None:
        """(K,): what each member's gradient grad (K, P) is divided by so that its norm is at most
        grad_clip_norm, as _clipped scales it (torch.nn.utils.clip_grad_norm_'s rule); None: no clipping."""
        clip = self.config.grad_clip_norm
        if clip <= 0:
            return None
        return ((torch.linalg.vector_norm(grad, dim=1) + 1e-6) / clip).clamp_(min=1.0)

    def _bias_corrections(self, step: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Adam's lr / (1 - beta1^t) and sqrt(1 - beta2^t), (K, 1) each, at step counts step (K,)."""
        beta1, beta2 = self.config.adam_betas
        return (self.config.lr / (1 - beta1**step)).unsqueeze(1), (1 - beta2**step).sqrt_().unsqueeze(1)

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Flat dict of tensors (safetensors-friendly): weights, Adam moments, counters."""
        return {
            "online.flat": self.online.flat.detach(),
            "target.flat": self.target.flat.detach(),
            "adam.exp_avg": self.exp_avg,
            "adam.exp_avg_sq": self.exp_avg_sq,
            "adam.step": self.adam_step,
            "target_update_count": self.target_update_count,
            "action_mask": self.action_mask,
        }

    @torch.no_grad()
    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Copy a `state_dict()` (from this learner's shape) into this learner, in place."""
        mine = self.state_dict()
        missing = sorted(set(mine) - set(state))
        if missing:
            raise ValueError(f"learner state is missing {missing}")
        for key, dst in mine.items():
            src = state[key].to(dst.device)
            if src.shape != dst.shape:
                raise ValueError(f"learner state {key} has shape {tuple(src.shape)}, expected {tuple(dst.shape)}")
            if key == "action_mask" and not torch.equal(src.to(torch.bool), dst):
                raise ValueError("learner state was saved with different expert action sets")
            dst.copy_(src)
