"""The torch dataset of windows of downsampled, normalised sequences, and the reference's training
sampler (protocol §1.4): per window a sequence uniform with replacement (not weighted by length),
then a start uniform in the dataset's range."""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset, Sampler, default_collate

from src.data.errors import DataError


class WindowDataset(Dataset):
    """Windows addressed by (sequence, start) pairs (TrainWindowSampler's) or by position i in
    ``windows``, a list of such pairs. Items: ``observed (observed_len, D)``, ``future
    (future_len, D)``, ``action`` and, by position, ``window`` = i (into ``dm.eval_windows``)."""

    def __init__(self, sequences, actions, observed_len: int, future_len: int, windows=()):
        self.sequences, self.actions = sequences, actions
        self.observed_len, self.future_len = observed_len, future_len
        self.windows = list(windows)

    def __len__(self) -> int:
        return len(self.windows)

    def __getitem__(self, index: int | tuple[int | str, int]) -> dict[str, Tensor]:
        seq, start = index if isinstance(index, tuple) else self.windows[index]
        frames = self.sequences[seq][start : start + self.observed_len + self.future_len]
        item = {
            "observed": frames[: self.observed_len],
            "future": frames[self.observed_len :],
            "action": torch.tensor(self.actions[seq], dtype=torch.long),
        }
        if not isinstance(index, tuple):
            item["window"] = torch.tensor(index, dtype=torch.long)
        return item


def _rank() -> int:
    dist = torch.distributed
    return dist.get_rank() if dist.is_available() and dist.is_initialized() else 0


class TrainWindowSampler(Sampler):
    """Endless batches of (seq, start) pairs, ended by the Trainer's ``max_steps``: batch k holds
    ``batch_size * draws`` windows drawn from (seed, k, DDP rank), so a resume starts at batch
    ``start`` (the restored global_step) with nothing to skip, and each rank draws its own
    without a DistributedSampler (``use_distributed_sampler=False``)."""

    def __init__(
        self,
        lengths: Sequence[int],
        window_len: int,
        low: int,
        batch_size: int,
        draws: int = 1,
        seed: int = 0,
        start: int = 0,
    ):
        self.highs = np.asarray(lengths, dtype=np.int64) - window_len
        self.eligible = np.flatnonzero(self.highs > low)
        if self.eligible.size == 0:
            raise DataError(
                f"no training sequence is long enough for a {window_len}-frame window "
                f"(lengths {list(lengths)}); shorten data.future_len"
            )
        self.low, self.batch_size, self.draws = low, batch_size, draws
        self.seed, self.start = seed, start

    def batch(self, k: int) -> list[tuple[int, int]]:
        rng = np.random.default_rng([self.seed, k, _rank()])
        seqs = self.eligible[rng.integers(0, self.eligible.size, size=self.batch_size * self.draws)]
        starts = rng.integers(self.low, self.highs[seqs])
        return list(zip(seqs.tolist(), starts.tolist(), strict=True))

    def __iter__(self) -> Iterator[list[tuple[int, int]]]:
        return map(self.batch, itertools.count(self.start))


def collate_with_discriminator_windows(items: list[dict[str, Tensor]]) -> dict[str, Tensor]:
    """A batch of 2B windows as the generator's B, with the discriminator's other B under "d":
    D and G see different windows in an iteration (protocol §6.6)."""
    half = len(items) // 2
    return {**default_collate(items[half:]), "d": default_collate(items[:half])}
