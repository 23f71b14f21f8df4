"""Human3.6M exp-map data (protocol §1.1-1.4, §2.1, §3.1)."""

from __future__ import annotations

import os
from collections.abc import Iterable

from src.data.base import MotionDataModule
from src.data.errors import DataError
from src.data.layout import H36M, H36M_TEST_SUBJECT, H36M_TRAIN_SUBJECTS, FileEntry, h36m_files
from src.data.windows import SRNN_PREFIX, SRNN_SUFFIX, srnn_h36m_starts

H36M_SUBJECTS = (1, 5, 6, 7, 8, 9, 11)


def parse_subjects(subjects: int | Iterable[int], what: str) -> list[int]:
    items = [subjects] if isinstance(subjects, int) else list(subjects)
    bad = [s for s in items if s not in H36M_SUBJECTS]
    if bad or not items:
        raise DataError(
            f"{what}: unknown H3.6M subject(s) {bad or items!r}; valid subjects are "
            f"{', '.join(map(str, H36M_SUBJECTS))}"
        )
    return sorted({int(s) for s in items})


class H36MDataModule(MotionDataModule):
    """H3.6M: train on subjects 1, 6, 7, 8, 9, 11, evaluate on subject 5 (protocol §1.2).
    ``eval_protocol="srnn"`` gives the reference's 8 windows per action (§3.1), alternating
    subactions 1 and 2, whose starts do not depend on ``future_len``. ``reference_angle_wrap``:
    Li et al.'s wrap of every exp-map triple before the statistics (§2.3), which alters the root
    translation of about a third of the training frames; off, the frames are used as they are."""

    spec, dataset_name = H36M, "h36m"
    conv_padding = "same"

    def __init__(
        self,
        data_dir: str | os.PathLike | None = None,
        train_subjects: Iterable[int] = H36M_TRAIN_SUBJECTS,
        test_subject: int = H36M_TEST_SUBJECT,
        val_subject: int | None = None,
        reference_angle_wrap: bool = False,
        **kwargs,
    ):
        super().__init__(data_dir, **kwargs)
        self.angle_wrap = bool(reference_angle_wrap)
        self.train_subjects = parse_subjects(train_subjects, "data.train_subjects")
        (self.test_subject,) = parse_subjects([test_subject], "data.test_subject")
        if self.test_subject in self.train_subjects:
            raise DataError(
                f"data.test_subject={self.test_subject} is also a training subject "
                f"{self.train_subjects}; the protocol keeps them disjoint (fix: remove it from "
                "data.train_subjects)"
            )
        # Mao et al. validate, and select their checkpoint, on S11 (shared docs/hisrep.md §1).
        self.val_subject = None
        if val_subject is not None:
            (self.val_subject,) = parse_subjects([val_subject], "data.val_subject")
            if self.val_subject in [*self.train_subjects, self.test_subject]:
                raise DataError(
                    f"data.val_subject={self.val_subject} is also a training or the test "
                    f"subject ({self.train_subjects}, {self.test_subject}); remove it from "
                    "data.train_subjects, or choose another"
                )
        if self.eval_protocol == "srnn" and self.window_len > SRNN_PREFIX + SRNN_SUFFIX:
            raise DataError(
                f"the srnn test windows reserve {SRNN_PREFIX + SRNN_SUFFIX} frames, but "
                f"observed_len + future_len = {self.window_len} (fix: future_len <= "
                f"{SRNN_PREFIX + SRNN_SUFFIX - self.observed_len}, or data.eval_protocol=random)"
            )

    def expected_files(self) -> tuple[list[FileEntry], list[FileEntry]]:
        train = h36m_files(self.train_subjects, self.actions)
        return train, h36m_files([self.test_subject], self.actions)

    def validation_files(self) -> list[FileEntry]:
        return [] if self.val_subject is None else h36m_files([self.val_subject], self.actions)

    def protocol_windows(self, lengths: list[int]) -> list[tuple[int, int]]:
        # lengths = [subaction 1, subaction 2]; the index into them is subaction - 1.
        return [(sub - 1, s) for sub, s in srnn_h36m_starts(*lengths, seed=self.eval_seed)]
