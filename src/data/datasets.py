"""The torch dataset over downsampled, normalised sequences, and the training batch sampler of
the reference (protocol §1.4): per window a sequence uniform with replacement (not weighted by
length), then a start uniform in the dataset's range. An "epoch" is ``steps_per_epoch`` batches."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset, Sampler

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
    """``steps_per_epoch`` batches of ``batch_size * draws_per_step`` (seq, start) pairs, seeded
    from (seed, epoch, DDP rank): reproducible, resumable, and different on each rank without a
    DistributedSampler (``use_distributed_sampler=False``)."""

    def __init__(
        self,
        lengths: Sequence[int],
        window_len: int,
        low: int,
        batch_size: int,
        steps_per_epoch: int,
        draws_per_step: int = 1,
        seed: int = 0,
    ):
        self.highs = np.asarray(lengths, dtype=np.int64) - window_len
        self.eligible = np.flatnonzero(self.highs > low)
        if self.eligible.size == 0:
            raise DataError(
                f"no training sequence is long enough for a {window_len}-frame window "
                f"(lengths {list(lengths)}); shorten data.future_len"
            )
        self.low, self.batch_size, self.steps_per_epoch = low, batch_size, steps_per_epoch
        self.draws_per_step, self.seed, self.epoch = draws_per_step, seed, 0
        # Batches of the current epoch already trained on before a mid-epoch resume: drawn
        # and dropped once, so the resumed run sees the batches the killed one would have.
        self.start_step = 0

    @property
    def sampler(self) -> TrainWindowSampler:  # Lightning calls batch_sampler.sampler.set_epoch
        return self

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.steps_per_epoch

    def __iter__(self) -> Iterator[list[tuple[int, int]]]:
        rng = np.random.default_rng([self.seed, self.epoch, _rank()])
        n = self.batch_size * self.draws_per_step
        skip, self.start_step = self.start_step, 0
        for step in range(self.steps_per_epoch):
            seqs = self.eligible[rng.integers(0, self.eligible.size, size=n)]
            starts = rng.integers(self.low, self.highs[seqs])
            if step >= skip:
                yield list(zip(seqs.tolist(), starts.tolist(), strict=True))
