"""Sparse updates in two forms: compact (eager) or static-shaped (compiled).

The eager step works on the few vehicles a rule concerns (the lane changers, the cars near a lane end):
it lists them with `nonzero`, which is cheap on the CPU but has a data-dependent shape (a host sync on a
GPU, a graph break for torch.compile). The static step visits every (env, vehicle) entry instead and
carries the selection as a mask. Both run the same formulas on the same elements; these helpers are the
only place where the two differ. `sel` is None in the compact form and a (M,) bool mask in the static one.
"""

from __future__ import annotations

import torch


def entries(mask: torch.Tensor, static: bool):
    """(bb, ii, sel): env and column indices (M,) of mask's (B, C) True entries. Compact: only those, sel
    None. Static: every entry (M = B C, row-major), sel = mask flattened."""
    if not static:
        bb, ii = mask.nonzero(as_tuple=True)
        return bb, ii, None
    b, c = mask.shape
    bb = torch.arange(b, device=mask.device).repeat_interleave(c)
    ii = torch.arange(c, device=mask.device).repeat(b)
    return bb, ii, mask.reshape(-1)


def none_left(bb: torch.Tensor, sel: torch.Tensor | None) -> bool:
    """Nothing selected, known without a host read: only the compact form can tell (and returns early)."""
    return sel is None and bb.numel() == 0


def narrow(sel: torch.Tensor | None, keep: torch.Tensor, *idx: torch.Tensor):
    """Keep the entries where keep (M,) holds: compact: (None, *each idx[keep]); static: (sel & keep, *idx)."""
    if sel is None:
        return (None, *(t[keep] for t in idx))
    return (sel & keep, *idx)


def put(t: torch.Tensor, bb: torch.Tensor, ii: torch.Tensor, value, sel: torch.Tensor | None) -> None:
    """t[bb, ii] = value where selected (every index pair is distinct in both forms)."""
    if sel is None:
        t[bb, ii] = value
    else:
        t[bb, ii] = torch.where(sel, value, t[bb, ii])


def ones(bb: torch.Tensor, sel: torch.Tensor | None) -> torch.Tensor:
    """1 per selected entry (M,) long, to count selected entries per env with index_add_ over bb."""
    return torch.ones_like(bb) if sel is None else sel.long()
