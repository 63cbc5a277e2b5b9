"""A stack of M independent MLPs evaluated with batched matrix products.

Every member is in_dim -> hidden -> ... -> out_dim with ReLU between layers (§4.1: 37 -> 256 -> 256 ->
4/3/2, the default); `MLPEnsemble.widths` is the one place the architecture is set, and the forward pass
(ensemble_forward), the layer views (unflatten) and the learner's written-out gradient
(dqn.td_loss_and_grad) all follow it. All of member m's weights live in row m of one parameter `flat` (M, P);
`params()` views it as the stacked layers w1 (M, in, h), b1 (M, 1, h), ..., wL (M, h, out), bL (M, 1, out),
so one `torch.baddbmm` per layer evaluates all members. Keeping a member in
one row makes selecting, updating and copying K members one indexed operation each instead
of six, which is most of the per-update overhead on a CPU.

Smaller action sets (the paper's 3- and 2-output networks) use the same out_dim-output member;
the outputs for actions outside the set are never read (the learner masks them to -inf before
any max/argmax and only regresses outputs of executed actions, which are inside the set).
Those outputs therefore get no gradient, and the used outputs depend only on the hidden layers
and their own columns of the last layer, so each member computes exactly the function of a
network with 4/3/2 outputs and learns exactly as it would.
"""

from __future__ import annotations

import math

import torch
from torch import nn

Params = tuple[torch.Tensor, ...]


def layer_outputs(params: Params, x: torch.Tensor) -> list[torch.Tensor]:
    """The input and every layer's output of stacked members: [x, h1, ..., hL-1, q], ReLU after every layer
    but the last. params: (w1, b1, ..., wL, bL), each (K, ...) as in `MLPEnsemble`; x: (K, B, in)."""
    outputs = [x]
    last = len(params) // 2 - 1
    for i, (w, b) in enumerate(zip(params[0::2], params[1::2])):
        h = torch.baddbmm(b, outputs[-1], w)
        outputs.append(h if i == last else torch.relu(h))
    return outputs


def ensemble_forward(params: Params, x: torch.Tensor) -> torch.Tensor:
    """Evaluate stacked members. params: (w1, b1, ..., wL, bL), each (K, ...) as in
    `MLPEnsemble`; x: (K, B, in) -> (K, B, out)."""
    return layer_outputs(params, x)[-1]


class MLPEnsemble(nn.Module):
    """M MLPs in_dim -> hidden -> ... -> out_dim with ReLU, stored stacked.

    hidden: the hidden layers' widths, or one width for the paper's two hidden layers.
    Member m's layer computes x @ w[m] + b[m]: w[m] is the transpose of an `nn.Linear.weight`.
    The state_dict holds the single tensor "flat" (M, P), P = sum of the layers' sizes.
    """

    def __init__(
        self,
        num_members: int,
        in_dim: int,
        out_dim: int,
        hidden: int | tuple[int, ...] = 256,
        device: torch.device | str | None = None,
        generator: torch.Generator | None = None,
    ) -> None:
        """generator: a CPU generator for the initial weights (None: torch's global one)."""
        super().__init__()
        self.num_members, self.in_dim, self.out_dim, self.hidden = num_members, in_dim, out_dim, hidden
        self.widths = (in_dim, *((hidden, hidden) if isinstance(hidden, int) else hidden), out_dim)
        layers = tuple(zip(self.widths[:-1], self.widths[1:]))
        self.shapes = tuple(shape for fi, fo in layers for shape in ((fi, fo), (1, fo)))
        self.sizes = tuple(a * b for a, b in self.shapes)
        # Drawn on the CPU (with a CPU generator) and then moved, so a seed gives the same
        # initial weights on every device.
        self.flat = nn.Parameter(torch.empty(num_members, sum(self.sizes)))
        with torch.no_grad():
            for (fan_in, _), w, b in zip(layers, self.params()[0::2], self.params()[1::2]):
                # nn.Linear's default init (kaiming_uniform with a=sqrt(5), and its bias rule) is
                # U(-1/sqrt(fan_in), 1/sqrt(fan_in)) for weight and bias, independently per member.
                bound = 1.0 / math.sqrt(fan_in)
                w.uniform_(-bound, bound, generator=generator)
                b.uniform_(-bound, bound, generator=generator)
        if device is not None:
            self.to(device)

    def unflatten(self, flat: torch.Tensor) -> Params:
        """flat: (K, P) -> the six layer tensors (K, ...), as views (differentiable)."""
        k = flat.shape[0]
        return tuple(part.view(k, *shape) for part, shape in zip(flat.split(self.sizes, dim=1), self.shapes))

    def params(self) -> Params:
        """(w1, b1, ..., wL, bL) of all members, views of `flat` (writing to them writes it)."""
        return self.unflatten(self.flat)

    def forward_rows(self, rows: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Members given by their rows (K, P) (of `flat` or a copy), x: (K, B, in) -> (K, B, out)."""
        return ensemble_forward(self.unflatten(rows), x)

    def gather(self, idx: torch.Tensor) -> torch.Tensor:
        """Rows of members idx (K,) long: (K, P), a differentiable copy."""
        return self.flat.index_select(0, idx)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, in), the same input for every member, or (M, B, in) -> (M, B, out)."""
        if x.dim() == 2:
            x = x.unsqueeze(0).expand(self.num_members, -1, -1)
        return ensemble_forward(self.params(), x)

    def forward_members(self, idx: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """idx: (K,) long member indices, x: (K, B, in) -> (K, B, out).

        Gradients reach `flat` through `index_select`, on rows idx only.
        """
        return self.forward_rows(self.gather(idx), x)

    @torch.no_grad()
    def copy_from(self, other: MLPEnsemble) -> None:
        """Overwrite every member with other's weights (e.g. online -> target network)."""
        self.flat.copy_(other.flat)
