"""The LightningDataModule of H3.6M and CMU: text files -> (cached) raw 50 Hz arrays -> Normalizer
of the raw training frames (§2.1) -> even frames (§1.3) -> normalised used dimensions -> training
windows (§1.4, §1.5), evaluation windows (§3, or ``random`` / ``strided``) and their export. A
partial copy is refused; with ``allow_partial`` the actions it cannot evaluate are reported."""

from __future__ import annotations

import logging
import os
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader

from src.data.archive import ensure_dataset, resolve_data_dir
from src.data.datasets import (
    TrainWindowSampler,
    WindowDataset,
    collate_with_discriminator_windows,
)
from src.data.errors import DataError
from src.data.layout import DatasetSpec, FileEntry, missing_files, parse_actions
from src.data.normalization import Normalizer
from src.data.reader import load_sequences
from src.data.windows import TRAIN_START_LOW, random_starts, strided_starts

log = logging.getLogger(__name__)

EVAL_PROTOCOLS = ("srnn", "random", "strided")


@dataclass(frozen=True)
class EvalWindow:
    """Frames [start, start + window_len) of ``sequence`` (the file key, ``S5/walking_1``);
    ``subaction`` is the H3.6M subaction (1 or 2) or the CMU file number k."""

    action: str
    sequence: str
    subaction: int
    start: int


def window_ids(windows: Iterable[EvalWindow]) -> list[str]:
    """One name per window, ``<sequence>@<start>`` (``S5/walking_1@1087``, in downsampled frames,
    §1.3); a window the random protocol draws again is ``...@start#k``, k = 2, 3, ..."""
    seen: Counter[str] = Counter()
    out = []
    for w in windows:
        name = f"{w.sequence}@{w.start}"
        seen[name] += 1
        out.append(name if seen[name] == 1 else f"{name}#{seen[name]}")
    return out


def _positive(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise DataError(f"data.{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


class MotionDataModule(L.LightningDataModule):
    """Loading, normalisation and windowing. Subclasses give ``expected_files()``, the (training,
    test) FileEntry lists of the configured actions, and ``protocol_windows(lengths)``, the
    reference test windows of one action as (index into its test files, start) pairs."""

    spec: DatasetSpec
    dataset_name: str  # spec.name; a class attribute, read from the class by load_trained
    conv_padding: str  # "same" on H3.6M, "valid" on CMU (protocol §6.7)
    angle_wrap: bool = False  # [L]'s H3.6M wrap before the statistics (§2.3); H3.6M's option
    # Milliseconds per downsampled frame, for the horizon labels: 40 ms (25 fps) on H3.6M and, as
    # the reference's tables have it, on CMU, most likely 30 Hz (protocol §1.5, [L] issue #4).
    frame_ms: int = 40

    def __init__(
        self,
        data_dir: str | os.PathLike | None = None,
        archive: str | os.PathLike | None = None,
        archive_dir: str | os.PathLike | None = None,
        actions: str | Iterable[str] = "all",
        observed_len: int = 50,
        future_len: int = 25,
        train_future_len: int | None = None,
        zero_root: bool = False,
        normalize: bool = True,
        batch_size: int = 16,
        eval_batch_size: int = 256,
        discriminator_windows: bool = False,
        eval_protocol: str = "srnn",
        eval_windows_per_action: int = 256,
        eval_stride: int = 10,
        eval_seed: int = 1234567890,
        val_stride: int = 1,
        allow_partial: bool = False,
        num_workers: int = 0,
        seed: int = 0,
        name: str | None = None,
    ):
        super().__init__()
        self.name = name or self.dataset_name  # the data config's (synthetic is in H3.6M's format)
        self.data_dir = resolve_data_dir(data_dir)
        self.archive, self.archive_dir = archive, archive_dir
        self.num_features = self.spec.n_columns
        self.actions = parse_actions(actions, self.spec)
        self.num_actions = len(self.actions)
        self.observed_len = _positive("observed_len", observed_len)
        self.future_len = _positive("future_len", future_len)
        self.window_len = self.observed_len + self.future_len
        # Training windows may predict fewer frames than the evaluation (HisRep: 10 of 25).
        self.train_future_len = _positive(
            "train_future_len", self.future_len if train_future_len is None else train_future_len
        )
        if discriminator_windows and self.train_future_len != self.future_len:
            raise DataError(
                f"data.train_future_len={train_future_len} with the adversarial regulariser: the "
                f"discriminator judges observed_len + future_len = {self.window_len} frames. Set "
                "train_future_len=null, or adversarial=none."
            )
        # The root's 6 columns (global translation and rotation) set to 0 when loaded, as Mao et
        # al.: the std rule then leaves them out. normalize=false: the used columns in radians.
        self.zero_root, self.normalize = bool(zero_root), bool(normalize)
        self.batch_size = _positive("batch_size", batch_size)
        self.eval_batch_size = _positive("eval_batch_size", eval_batch_size)
        # With the regulariser a batch carries D's own windows under "d" (protocol §6.6).
        self.discriminator_windows = bool(discriminator_windows)
        if eval_protocol not in EVAL_PROTOCOLS:
            raise DataError(
                f"unknown data.eval_protocol {eval_protocol!r}; valid: {', '.join(EVAL_PROTOCOLS)}"
            )
        self.eval_protocol = eval_protocol
        self.eval_windows_per_action = _positive("eval_windows_per_action", eval_windows_per_action)
        self.eval_stride = _positive("eval_stride", eval_stride)
        self.eval_seed = _positive("eval_seed", eval_seed, 0)
        if self.eval_seed >= 2**32:  # the protocol's RandomState would refuse it deep in setup()
            raise DataError(f"data.eval_seed must be below 2**32 (4294967296), got {eval_seed}")
        self.val_stride = _positive("val_stride", val_stride)
        self.allow_partial = bool(allow_partial)
        self.num_workers = _positive("num_workers", num_workers, 0)
        self.seed = _positive("seed", seed, 0)
        self.normalizer: Normalizer | None = None
        self.eval_windows: list[EvalWindow] = []
        self.absent_actions: dict[str, str] = {}
        self.missing_files: list[str] = []
        self.untrained_actions: list[str] = []  # configured actions without any training file
        self._given_normalizer: Normalizer | None = None
        self._stage: str | None = None

    def set_normalizer(self, normalizer: Normalizer) -> None:
        """A checkpoint's statistics: then setup("validate"|"test") reads only the test files."""
        self._given_normalizer = normalizer

    @property
    def _eval_only(self) -> bool:
        return self._given_normalizer is not None and self._stage != "fit"

    @property
    def pose_dim(self) -> int:
        return self._require_setup().pose_dim

    def _require_setup(self) -> Normalizer:
        if self.normalizer is None:
            raise DataError(
                f"{type(self).__name__}: call prepare_data() and setup() before using the data"
            )
        return self.normalizer

    def validation_files(self) -> list[FileEntry]:
        """The files of a validation split (H3.6M's ``val_subject``); none: training validates
        on the test windows, as the papers (the protocol has no validation split, §8)."""
        return []

    def prepare_data(self) -> None:
        """Unpack the archive if needed and parse every present file into the cache."""
        train, test, val = self._locate()
        present = [e.relpath for e in train + test + val if e.relpath not in self.missing_files]
        load_sequences(self.data_dir, self.spec, present)

    def _locate(self) -> tuple[list[FileEntry], list[FileEntry], list[FileEntry]]:
        ensure_dataset(self.spec, self.data_dir, self.archive, self.archive_dir)
        train, test = self.expected_files()
        train, val = ([], []) if self._eval_only else (train, self.validation_files())
        self.missing_files = missing = missing_files(self.data_dir, train + test + val)
        if missing and not self.allow_partial:
            spec = self.spec
            raise DataError(
                f"{len(missing)} expected {spec.name} file(s) are missing under {self.data_dir}:"
                "\n  " + "\n  ".join(missing) + "\nThe full protocol needs all of them. Fix: get "
                f"the complete archive (download {spec.source} ({spec.url})), delete "
                f"{self.data_dir / spec.root} and run again; or, for a copy that stays partial, "
                "export MOTION_ALLOW_PARTIAL=true (or data.allow_partial=true) to use the files "
                "that exist and report the actions that cannot be evaluated as absent."
            )
        return train, test, val

    def setup(self, stage: str | None = None) -> None:
        """Load, normalise and window the data (once; later calls are no-ops)."""
        if self.normalizer is not None:
            return
        self._stage = stage
        train, test, val = self._locate()
        missing = set(self.missing_files)
        # allow_partial (else _locate raised): what is missing, by kind, and what is done.
        if missing:
            n_train = sum(e.relpath in missing for e in train)
            if self._eval_only:
                kind, doing = "test ", "evaluating with"
                counted = "training files are not needed: the checkpoint holds the normalisation"
            else:
                kind, counted = "", f"{n_train} training, {len(missing) - n_train} test"
                doing = "training on" if stage == "fit" else "normalising and evaluating with"
            # One line: a partial copy is the machine's lasting fact, and every command said
            # it with the whole list (20 lines on this project's H3.6M copy).
            log.warning(
                f"data.allow_partial=true: {len(missing)} {self.spec.name} {kind}file(s) are "
                f"missing under {self.data_dir} ({counted}); {doing} the files that exist, the "
                f"actions without their test files reported as absent (hydra.verbose={__name__}"
                " on the command line lists the files)"
            )
            log.debug("missing under %s:\n  %s", self.data_dir, "\n  ".join(self.missing_files))
        train = [e for e in train if e.relpath not in missing]
        present_test = [e for e in test if e.relpath not in missing]
        val = [e for e in val if e.relpath not in missing]
        files = [e.relpath for e in train + present_test + val]
        raw = load_sequences(self.data_dir, self.spec, files)
        if self.zero_root:  # load_sequences' arrays are this call's own
            for frames in raw.values():
                frames[:, :6] = 0
        if not train and not self._eval_only:
            raise DataError(
                f"no training file of the configured actions exists under {self.data_dir} "
                f"(missing: {', '.join(self.missing_files)})"
            )

        # Statistics from the raw 50 Hz training frames, before downsampling (protocol §2.1).
        normalizer = self._given_normalizer or Normalizer.from_sequences(
            [raw[e.relpath] for e in train], wrap=self.angle_wrap, scale=self.normalize
        )
        seqs = [normalizer.normalize(torch.from_numpy(raw[e.relpath][::2].copy())) for e in train]
        self._train_lengths = [len(s) for s in seqs]
        self._train_dataset = WindowDataset(
            seqs,
            [self.actions.index(e.action) for e in train],
            self.observed_len,
            self.train_future_len,
        )
        # Not known when evaluating a checkpoint (no training file is read): it carries its own.
        if not self._eval_only:
            self.untrained_actions = [a for a in self.actions if all(e.action != a for e in train)]
        if self.untrained_actions:
            log.warning(
                "no training file for action(s) %s: they are evaluated but never trained on",
                ", ".join(self.untrained_actions),
            )

        # Evaluation windows, action by action in canonical order.
        self.absent_actions, self.eval_windows = {}, []
        self._test_entries = {a: [e for e in test if e.action == a] for a in self.actions}
        self._test_raw = {e.key: raw[e.relpath][::2].copy() for e in present_test}
        for action, entries in self._test_entries.items():
            absent = [e.relpath for e in entries if e.relpath in missing]
            if absent:
                self.absent_actions[action] = "missing test file(s): " + ", ".join(absent)
                continue
            try:
                windows = self._action_windows([len(self._test_raw[e.key]) for e in entries])
            except DataError as exc:
                self.absent_actions[action] = f"test sequences too short ({exc})"
                continue
            self.eval_windows += [
                EvalWindow(action, entries[i].key, entries[i].index, s) for i, s in windows
            ]
        if self.absent_actions:
            log.warning(
                "%d action(s) cannot be evaluated and are reported as absent: %s",
                len(self.absent_actions),
                "; ".join(f"{a} ({why})" for a, why in self.absent_actions.items()),
            )
        if not self.eval_windows:
            raise DataError(
                f"no configured action can be evaluated: {self.absent_actions} (fix: provide the "
                "test files listed above)"
            )
        seqs = {k: normalizer.normalize(torch.from_numpy(f)) for k, f in self._test_raw.items()}
        labels = {e.key: self.actions.index(e.action) for e in present_test}
        pairs = [(w.sequence, w.start) for w in self.eval_windows]
        self._eval_dataset = WindowDataset(seqs, labels, self.observed_len, self.future_len, pairs)
        self._val_dataset = self._validation_split(val, raw, normalizer) if val else None
        self.normalizer = normalizer

    def _validation_split(self, files: list[FileEntry], raw, normalizer) -> WindowDataset:
        """Every window of the validation files, a start every ``val_stride`` frames."""
        seqs = [normalizer.normalize(torch.from_numpy(raw[e.relpath][::2].copy())) for e in files]
        pairs = strided_starts([len(s) for s in seqs], self.window_len, self.val_stride)
        labels = [self.actions.index(e.action) for e in files]
        log.info(
            "validating on %d windows of %s (every %d frames), not on the test windows; "
            "src.eval evaluates the test windows",
            len(pairs), ", ".join(sorted({e.relpath.split("/")[-2] for e in files})),
            self.val_stride,
        )  # fmt: skip
        return WindowDataset(seqs, labels, self.observed_len, self.future_len, pairs)

    def leave_out(self, absent: dict[str, str]) -> None:
        """Evaluate without the windows of these actions, reported absent with the reason."""
        self.eval_windows = [w for w in self.eval_windows if w.action not in absent]
        self._eval_dataset.windows = [(w.sequence, w.start) for w in self.eval_windows]
        self.absent_actions.update(absent)

    def _action_windows(self, lengths: list[int]) -> list[tuple[int, int]]:
        low = TRAIN_START_LOW[self.dataset_name]
        if self.eval_protocol == "srnn":
            return self.protocol_windows(lengths)
        if self.eval_protocol == "random":
            return random_starts(
                lengths, self.eval_windows_per_action, self.window_len, low, self.eval_seed
            )
        windows = strided_starts(lengths, self.window_len, self.eval_stride, low)
        if not windows:
            raise DataError(f"no {self.window_len}-frame window fits in lengths {lengths}")
        return windows

    def _loader(self, dataset: WindowDataset, **kwargs) -> DataLoader:
        return DataLoader(
            dataset,
            num_workers=self.num_workers,
            persistent_workers=self.num_workers > 0,
            # Its own generator for the workers' base seed: drawn from the global one, which the
            # dropout masks use, it would shift every later mask of a run resumed mid-epoch.
            generator=torch.Generator().manual_seed(self.seed),
            # Pinned batches let the Trainer's copy to the GPU run without blocking the host.
            pin_memory=self.trainer is not None
            and self.trainer.strategy.root_device.type == "cuda",
            **kwargs,
        )

    def train_dataloader(self) -> DataLoader:
        draws = 2 if self.discriminator_windows else 1
        sampler = TrainWindowSampler(
            self._train_lengths,
            self.observed_len + self.train_future_len,
            TRAIN_START_LOW[self.dataset_name],
            self.batch_size,
            draws,
            self.seed,
            # The Trainer restores a checkpoint's step before it asks for the loaders.
            start=self.trainer.global_step if self.trainer is not None else 0,
        )
        collate = collate_with_discriminator_windows if draws == 2 else None
        return self._loader(self._train_dataset, batch_sampler=sampler, collate_fn=collate)

    def test_dataloader(self) -> DataLoader:
        return self._loader(self._eval_dataset, batch_size=self.eval_batch_size, shuffle=False)

    def val_dataloader(self) -> DataLoader:
        """In training, the validation split where there is one; else the test windows, as the
        papers: the protocol has none (§8). src.eval (stage validate) gets the test windows."""
        if self._stage == "fit" and getattr(self, "_val_dataset", None) is not None:
            return self._loader(self._val_dataset, batch_size=self.eval_batch_size, shuffle=False)
        return self.test_dataloader()

    def raw_window(self, index: int) -> np.ndarray:
        """Downsampled raw (F columns) frames of ``eval_windows[index]``, observed then future."""
        self._require_setup()
        w = self.eval_windows[index]
        return self._test_raw[w.sequence][w.start : w.start + self.window_len].copy()

    def test_sequence(self, action: str, index: int = 0) -> np.ndarray:
        """Downsampled raw test sequence ``index`` of ``action`` (0: subaction 1, CMU's ``_1``)."""
        self._require_setup()
        entries = self._test_entries.get(action, [])
        if not 0 <= index < len(entries):
            raise DataError(
                f"{action} has no test sequence {index}: {len(entries)} are loaded (configured "
                f"actions: {', '.join(self.actions)})"
            )
        entry = entries[index]
        if entry.key not in self._test_raw:
            raise DataError(f"{self.data_dir / entry.relpath}: test file is missing")
        return self._test_raw[entry.key].copy()
