"""Sparse updates in two forms: compact (eager) or static-shaped (compiled).

The eager step works on the few vehicles a rule concerns (the lane changers, the cars near a lane end):
it lists them with `nonzero`, which is cheap on the CPU but has a data-dependent shape (a host sync on a
GPU, a graph break for torch.compile). The static step visits every (env, vehicle) entry instead and
carries the selection as a mask. Both run the same formulas on the same elements; these helpers are the
only place where the two differ. `sel` is None in the compact form and a (M,) bool mask in the static one.

Where the selections are large (lateral control, MOBIL, the aborts: thousands of entries at 2,048 envs)
their values are read and written through flat (row-major) indices, env * C + column (flat_index), with
take_flat and put_flat (index_select / take, index_copy_): on the CPU two-tensor advanced indexing
(t[bb, ii], put) takes a general path that costs 2-4x as much there (docs/log/benchmarks-history.md, session 16). The
rarer rules (lane ends, cooperative merging, the adversary) keep the plainer t[bb, ii].
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


# Below this many indices torch.take (one call) beats the three of a flat index_select; above it
# index_select's gather loop wins (1.4x at 10^5 indices). `python scripts/cpu_ops.py costs`: 1.2 vs 5.4 us at
# 26 indices, about even at 5,000 (docs/log/benchmarks-history.md, session 12).
TAKE_MAX = 4096


def take_flat(t: torch.Tensor, flat: torch.Tensor) -> torch.Tensor:
    """t's elements at flat (row-major) indices of any shape (faster than advanced indexing with index
    pairs or triples)."""
    if flat.numel() <= TAKE_MAX:
        return torch.take(t, flat)
    return t.reshape(-1).index_select(0, flat.reshape(-1)).view(flat.shape)


def flat_index(bb: torch.Tensor, ii: torch.Tensor, columns: int) -> torch.Tensor:
    """bb * columns + ii: the entries' flat indices into a (B, columns) tensor, in one operation."""
    return torch.add(ii, bb, alpha=columns)


def none_left(bb: torch.Tensor, sel: torch.Tensor | None) -> bool:
    """Nothing selected, known without a host read: only the compact form can tell (and returns early)."""
    return sel is None and bb.numel() == 0


def narrow(sel: torch.Tensor | None, keep: torch.Tensor, *idx: torch.Tensor):
    """Keep the entries where keep (M,) holds: compact: (None, *each idx[keep]); static: (sel & keep, *idx)."""
    if sel is None:
        pos = keep.nonzero().squeeze(1)  # once for all of idx (t[keep] would list them again for each)
        return (None, *(t.index_select(0, pos) for t in idx))
    return (sel & keep, *idx)


def put_flat(t: torch.Tensor, flat: torch.Tensor, value, sel: torch.Tensor | None) -> None:
    """put with the entries' flat indices (flat_index); value: (M,) of t's dtype or a Python scalar."""
    if sel is not None:
        value = torch.where(sel, value, take_flat(t, flat))
    elif not isinstance(value, torch.Tensor):
        t.view(-1).index_fill_(0, flat, value)
        return
    t.view(-1).index_copy_(0, flat, value)


def put(t: torch.Tensor, bb: torch.Tensor, ii: torch.Tensor, value, sel: torch.Tensor | None) -> None:
    """t[bb, ii] = value where selected (every index pair is distinct in both forms)."""
    if sel is None:
        t[bb, ii] = value
    else:
        t[bb, ii] = torch.where(sel, value, t[bb, ii])


def ones(bb: torch.Tensor, sel: torch.Tensor | None) -> torch.Tensor:
    """1 per selected entry (M,) long, to count selected entries per env with index_add_ over bb."""
    return torch.ones_like(bb) if sel is None else sel.long()
