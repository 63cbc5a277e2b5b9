"""One circular replay buffer per expert (Algorithm 1's D_i,j), all held in shared tensors.

Storage is flat, (M * capacity + 1, ...): member m's buffer is rows [m*capacity, (m+1)*capacity),
and the last row is a write-only scratch row. Rows that must be dropped (member -1, i.e. the
fallback action that no expert owns) are written there instead of being filtered out, so adding
needs no boolean indexing and therefore no host synchronisation on a GPU.

Memory: M * capacity * (2 * obs_dim * 4 + 8 + 4 + 1 [+ 4 with cost]) bytes, about
M * capacity * (2 * obs_dim + 4) * 4: 11 experts x 100_000 x 37-dim observations = 344 MB.
"""

from __future__ import annotations

import torch

_FIELDS = ("obs", "action", "reward", "next_obs", "done")


class ExpertReplay:
    """Circular buffers for `num_members` experts on one device.

    `done` is true only for termination (collision, success, failure), never for the
    time-limit truncation at the end of an episode, so truncated transitions still bootstrap.
    """

    def __init__(
        self,
        num_members: int,
        obs_dim: int,
        capacity: int = 100_000,
        device: torch.device | str | None = None,
        with_cost: bool = False,
    ) -> None:
        self.num_members, self.obs_dim, self.capacity = num_members, obs_dim, capacity
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        rows = num_members * capacity + 1  # + the scratch row for dropped transitions
        dev = self.device
        self.storage: dict[str, torch.Tensor] = {
            "obs": torch.zeros(rows, obs_dim, device=dev),
            "action": torch.zeros(rows, dtype=torch.long, device=dev),
            "reward": torch.zeros(rows, device=dev),
            "next_obs": torch.zeros(rows, obs_dim, device=dev),
            "done": torch.zeros(rows, dtype=torch.bool, device=dev),
        }
        if with_cost:
            self.storage["cost"] = torch.zeros(rows, device=dev)
        self.ptr = torch.zeros(num_members, dtype=torch.long, device=dev)  # next write slot
        self.size = torch.zeros(num_members, dtype=torch.long, device=dev)  # (M,) filled rows
        self._members = torch.arange(num_members, device=dev)

    def _scatter(self, member: torch.Tensor, src: torch.Tensor, data: dict[str, torch.Tensor]) -> None:
        """Write rows data[k][src] (N of them) into the buffers of member (N,); member -1 drops."""
        kept = member >= 0
        onehot = (member.unsqueeze(1) == self._members).long()  # (N, M); all-zero row for -1
        count = onehot.sum(0)  # (M,) rows arriving per member
        safe_member = member.clamp(min=0)
        rank = (onehot.cumsum(0) - 1).gather(1, safe_member.unsqueeze(1)).squeeze(1)  # order within member
        # More than `capacity` rows for one member in one call: only the last `capacity` survive,
        # which also keeps the write positions of one call distinct.
        kept = kept & (rank >= count[safe_member] - self.capacity)
        pos = (self.ptr[safe_member] + rank) % self.capacity
        scratch = self.num_members * self.capacity
        row = torch.where(kept, safe_member * self.capacity + pos, torch.full_like(pos, scratch))
        for key, value in data.items():
            self.storage[key][row] = value.to(self.device)[src].to(self.storage[key].dtype)
        self.ptr = (self.ptr + count) % self.capacity
        self.size = torch.clamp(self.size + count, max=self.capacity)

    def _data(self, obs, action, reward, next_obs, done, cost) -> dict[str, torch.Tensor]:
        data = dict(zip(_FIELDS, (obs, action, reward, next_obs, done)))
        if "cost" in self.storage:
            if cost is None:
                raise ValueError("this ExpertReplay was built with_cost=True: pass cost (B,) to add()")
            data["cost"] = cost
        elif cost is not None:
            raise ValueError("cost given, but this ExpertReplay was built with with_cost=False")
        return data

    def add(self, member, obs, action, reward, next_obs, done, cost=None) -> None:
        """Store B transitions, each in the buffer of the expert that acted.

        member: (B,) long in [-1, M); -1 (the gate's fallback) drops the row.
        obs, next_obs: (B, obs_dim) float; action: (B,) long; reward: (B,) float;
        done: (B,) bool, termination only; cost: (B,) float when built with_cost.
        """
        data = self._data(obs, action, reward, next_obs, done, cost)
        self._scatter(member.to(self.device), torch.arange(member.shape[0], device=self.device), data)

    def add_shared(self, member_mask, obs, action, reward, next_obs, done, cost=None) -> None:
        """Store transition b in every member m with member_mask[b, m] (B, M) bool.

        For the off-policy option "share with every expert whose action set contains the
        executed action": member_mask = expert_action_mask()[:, action].T.
        """
        batch = member_mask.shape[0]
        data = self._data(obs, action, reward, next_obs, done, cost)
        member = torch.where(member_mask.to(self.device), self._members, -1).reshape(-1)  # (B*M,) row-major
        src = torch.arange(batch, device=self.device).repeat_interleave(self.num_members)
        self._scatter(member, src, data)

    def sample(
        self, members: torch.Tensor, batch_size: int, generator: torch.Generator | None = None
    ) -> dict[str, torch.Tensor]:
        """Uniform with replacement from each member's filled rows.

        members: (K,) long. Returns {"obs": (K, batch, obs_dim), "action": (K, batch), "reward",
        "next_obs", "done"[, "cost"]}. A member with size 0 returns zero rows (check `size` first).
        """
        members = members.to(self.device)
        u = torch.rand(members.shape[0], batch_size, generator=generator, device=self.device)
        return self.sample_at(members, u)

    def sample_at(self, members: torch.Tensor, u: torch.Tensor) -> dict[str, torch.Tensor]:
        """`sample` at given uniform draws u (K, batch) in [0, 1): row floor(u x size) of each member's
        filled rows. No host read (drawing u outside lets a compiled graph take it as an input)."""
        size = self.size[members].unsqueeze(1)
        slot = (u * size).long().clamp_(max=self.capacity - 1)
        row = members.unsqueeze(1) * self.capacity + slot
        # index_select on the flat rows: the same values as value[row], without advanced indexing's set-up
        flat = row.reshape(-1)
        return {key: value.index_select(0, flat).view(*row.shape, *value.shape[1:]) for key, value in self.storage.items()}

    def _filled_rows(self, size: torch.Tensor) -> torch.Tensor:
        """Row indices of the filled part, member by member: rows [m*capacity, m*capacity + size[m]), then
        the scratch row (so that a round trip restores the storage bit for bit).

        A buffer fills from slot 0 and wraps only once full, so its filled slots are always 0..size-1.
        """
        sizes = [int(n) for n in size.tolist()]
        scratch = torch.full((1,), self.num_members * self.capacity, dtype=torch.long, device=self.device)
        return torch.cat([torch.arange(n, device=self.device) + m * self.capacity for m, n in enumerate(sizes)]
                         + [scratch])

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Flat dict of tensors (safetensors-friendly) holding only the filled rows (sum(size), ...), so an
        early checkpoint is small; loading puts them back where they were."""
        rows = self._filled_rows(self.size)
        state = {f"replay.{k}": v[rows] for k, v in self.storage.items()}
        state["replay.ptr"], state["replay.size"] = self.ptr, self.size
        state["replay.capacity"] = torch.tensor([self.capacity])
        return state

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        expected = [f"replay.{k}" for k in self.storage] + ["replay.ptr", "replay.size", "replay.capacity"]
        missing = [k for k in expected if k not in state]
        if missing:
            raise ValueError(f"replay state is missing {missing}")
        if state["replay.capacity"].numel() != 1 or int(state["replay.capacity"]) != self.capacity:
            raise ValueError(f"replay state has capacity {state['replay.capacity'].tolist()} (shape mismatch), "
                             f"this buffer {self.capacity}")
        size, ptr = state["replay.size"], state["replay.ptr"]
        if size.shape != (self.num_members,) or ptr.shape != (self.num_members,):
            raise ValueError(f"replay.size/ptr have shape {tuple(size.shape)}/{tuple(ptr.shape)}, "
                             f"expected ({self.num_members},) for {self.num_members} members")
        size, ptr = size.to(self.device, torch.long), ptr.to(self.device, torch.long)
        if bool((size < 0).any() | (size > self.capacity).any() | (ptr < 0).any() | (ptr >= self.capacity).any()):
            raise ValueError(f"replay.size/ptr out of range for a buffer of capacity {self.capacity}")
        rows = self._filled_rows(size)
        for key in self.storage:
            value = state[f"replay.{key}"]
            want = (rows.numel(), *self.storage[key].shape[1:])
            if tuple(value.shape) != want:
                raise ValueError(f"replay.{key} has shape {tuple(value.shape)}, expected {want}")
        for key, store in self.storage.items():
            store.zero_()
            store[rows] = state[f"replay.{key}"].to(self.device, store.dtype)
        self.ptr, self.size = ptr.clone(), size.clone()
