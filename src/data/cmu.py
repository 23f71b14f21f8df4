"""CMU mocap data in Li et al.'s 8-action split (protocol §1.5, §2.3, §3.2, §6.7)."""

from __future__ import annotations

import os
from collections.abc import Iterable

from src.data.base import MotionDataModule
from src.data.layout import CMU, FileEntry, cmu_files
from src.data.windows import cmu_test_starts


class CMUDataModule(MotionDataModule):
    """CMU: train files ``{action}_1..5``, test file ``{action}_1`` (protocol §1.5).

    ``eval_protocol="srnn"`` gives the reference's 8 windows per action from the single test
    file (§3.2); their starts depend on ``future_len``. No angle wrapping, no start offset of 16,
    VALID convolution padding (§6.7).
    """

    dataset_name = "cmu"
    conv_padding = "valid"

    def __init__(
        self,
        data_dir: str | os.PathLike | None,
        archive: str | os.PathLike | None = None,
        archive_dir: str | os.PathLike | None = None,
        actions: str | Iterable[str] = "all",
        observed_len: int = 50,
        future_len: int = 25,
        batch_size: int = 16,
        eval_batch_size: int = 256,
        steps_per_epoch: int = 1000,
        eval_protocol: str = "srnn",
        eval_windows_per_action: int = 256,
        eval_stride: int = 10,
        eval_seed: int = 1234567890,
        allow_partial: bool = False,
        num_workers: int = 0,
        seed: int = 0,
    ):
        super().__init__(
            CMU,
            data_dir,
            archive,
            archive_dir,
            actions,
            observed_len,
            future_len,
            batch_size,
            eval_batch_size,
            steps_per_epoch,
            eval_protocol,
            eval_windows_per_action,
            eval_stride,
            eval_seed,
            allow_partial,
            num_workers,
            seed,
        )

    def expected_files(self) -> tuple[list[FileEntry], list[FileEntry]]:
        return cmu_files(self.actions, "train"), cmu_files(self.actions, "test")

    def protocol_windows(self, lengths: list[int]) -> list[tuple[int, int]]:
        starts = cmu_test_starts(
            lengths[0], self.observed_len, self.future_len, seed=self.eval_seed
        )
        return [(0, s) for s in starts]
