"""CMU mocap data in Li et al.'s 8-action split (protocol §1.5, §2.3, §3.2, §6.7)."""

from __future__ import annotations

from src.data.base import MotionDataModule
from src.data.layout import CMU, FileEntry, cmu_files
from src.data.windows import cmu_test_starts


class CMUDataModule(MotionDataModule):
    """CMU: train files ``{action}_1..5``, test file ``{action}_1`` (protocol §1.5);
    ``eval_protocol="srnn"``: the reference's 8 windows per action from the test file (§3.2),
    whose starts depend on ``future_len``. No angle wrapping, no start offset of 16, VALID
    convolution padding (§6.7)."""

    spec, dataset_name = CMU, "cmu"
    conv_padding = "valid"

    def expected_files(self) -> tuple[list[FileEntry], list[FileEntry]]:
        return cmu_files(self.actions, "train"), cmu_files(self.actions, "test")

    def protocol_windows(self, lengths: list[int]) -> list[tuple[int, int]]:
        starts = cmu_test_starts(
            lengths[0], self.observed_len, self.future_len, seed=self.eval_seed
        )
        return [(0, s) for s in starts]
