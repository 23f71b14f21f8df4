"""Per-column z-scoring and the used/ignored column split (protocol §2), from the raw 50 Hz frames
of all loaded training files (§2.1): population mean and std per column; a column is *used* iff
its std >= 1e-4, the std of the others is reset to 1. ``normalize`` keeps the used columns (D of
F); ``unnormalize`` puts them back, the ignored ones as the training mean, as the reference's
zero-fill-then-scale does (§2.2). ``wrap``: Li et al.'s H3.6M variant (§2.3), every exp-map triple
wrapped to the norm θ mod 2π before the statistics and before normalising, off by default.
Buffers: every checkpoint of the owning module holds them."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor, nn

from src.data.errors import DataError

STD_THRESHOLD = 1e-4


def wrap_angles(x: Tensor) -> Tensor:
    """(..., F) frames, each of the F/3 triples scaled to the norm θ mod 2π, as [L] (§2.3): a
    joint's rotation is unchanged (θ and θ - 2π turn alike), the root translation triple is not.
    [L] divides by θ + eps; here θ itself (equal but for eps)."""
    r = x.unflatten(-1, (-1, 3))
    theta = r.norm(dim=-1, keepdim=True)
    scale = torch.where(theta > 0, torch.remainder(theta, 2 * torch.pi) / theta, 1.0)
    return (r * scale).flatten(-2)


class Normalizer(nn.Module):
    """Maps raw exp-map frames (..., F) to normalised used dimensions (..., D) and back."""

    mean: Tensor
    std: Tensor
    used: Tensor
    wrap: Tensor

    def __init__(self, mean: Tensor, std: Tensor, used: Tensor, wrap: bool = False):
        super().__init__()
        self.register_buffer("mean", mean.to(torch.float32).clone())
        self.register_buffer("std", std.to(torch.float32).clone())
        self.register_buffer("used", used.to(torch.bool).clone())
        self.register_buffer("wrap", torch.tensor(bool(wrap)))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # A checkpoint from before the switch holds no flag: its frames were not wrapped.
        state_dict.setdefault(prefix + "wrap", torch.tensor(False))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @classmethod
    def from_sequences(
        cls,
        sequences: Sequence[np.ndarray],
        threshold: float = STD_THRESHOLD,
        wrap: bool = False,
        scale: bool = True,
    ) -> Normalizer:
        """Statistics of the frames of all ``sequences`` (N_i, F), not concatenated; two float64
        passes (mean, squared deviations) keep the columns that decide the used set exact.
        ``scale=False``: the used columns pass unchanged (mean 0, std 1; Mao et al. train on
        raw radians), the ignored ones still come back as their mean."""
        seqs = [np.asarray(s) for s in sequences]
        if wrap:
            seqs = [wrap_angles(torch.from_numpy(s.astype(np.float64))).numpy() for s in seqs]
        n = sum(len(s) for s in seqs)
        if n == 0:
            raise DataError("Normalizer statistics need at least one training frame, got none")
        mean = sum(s.sum(axis=0, dtype=np.float64) for s in seqs) / n
        std = np.sqrt(sum(np.square(s.astype(np.float64) - mean).sum(axis=0) for s in seqs) / n)
        if not np.isfinite(std).all():  # a non-finite mean makes its std non-finite too
            raise DataError("Normalizer statistics not finite: the training frames hold NaN/inf")
        used = std >= threshold
        std = np.where(used, std, 1.0)
        if not scale:
            mean, std = np.where(used, 0.0, mean), np.ones_like(std)
        return cls(torch.from_numpy(mean), torch.from_numpy(std), torch.from_numpy(used), wrap)

    @property
    def num_features(self) -> int:  # F: raw columns (99 H3.6M, 117 CMU)
        return int(self.used.numel())

    @property
    def pose_dim(self) -> int:  # D: used columns (54 H3.6M, 70 CMU)
        return int(self.used.sum())

    @property
    def dim_used(self) -> Tensor:  # indices of the used columns, ascending
        return torch.nonzero(self.used).flatten()

    def _check(self, x: Tensor, size: int, name: str) -> None:
        if x.shape[-1] != size:
            raise DataError(
                f"Normalizer.{name} expects a last dimension of {size}, got shape {tuple(x.shape)}"
            )

    def normalize(self, x: Tensor) -> Tensor:
        """(..., F) raw frames -> (..., D) normalised used dimensions (§2.1)."""
        self._check(x, self.num_features, "normalize")
        x = wrap_angles(x) if self.wrap else x
        return ((x - self.mean.to(x)) / self.std.to(x)).index_select(-1, self.dim_used.to(x.device))

    def unnormalize(self, z: Tensor) -> Tensor:
        """(..., D) normalised -> (..., F) raw; ignored columns come back as the mean (§2.2)."""
        self._check(z, self.pose_dim, "unnormalize")
        full = z.new_zeros(*z.shape[:-1], self.num_features)
        full = full.index_copy(-1, self.dim_used.to(z.device), z)
        return full * self.std.to(z) + self.mean.to(z)
