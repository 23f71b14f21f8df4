"""Checkpoint files: `last.ckpt`, the resume point (LastCheckpoint), and the lean
`best-iterNNNNNN.ckpt` for evaluation (BestCheckpoint); reading one with clear errors
(`read_checkpoint`), an older one converted (`upgrade`). Whether one fits a config or the data:
src/build.py."""

from __future__ import annotations

import contextlib
import logging
import signal
import zipfile
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import torch
from lightning.pytorch.callbacks import Checkpoint, ModelCheckpoint

from src.data.files import atomic_write

log = logging.getLogger(__name__)

LAST = "last.ckpt"


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable, or does not match the requested config."""


class TrainingInterrupted(RuntimeError):
    """SIGINT or SIGTERM stopped training; `path` is the resumable checkpoint written."""

    def __init__(self, signum: int, path: Path, iteration: int):
        self.signum, self.path, self.iteration = signum, path, iteration
        super().__init__(
            f"{signal.Signals(signum).name} received: stopped after iteration {iteration} and "
            f"wrote {path}. Resume with: python -m src.train ckpt_path={path}"
        )


class LastCheckpoint(Checkpoint):
    """Writes `last.ckpt` atomically after every validation, every `every` iterations (0: off)
    and, on SIGINT/SIGTERM, after the iteration in progress (and its validation, if one is due),
    then stops with TrainingInterrupted; a second signal aborts at once. (Lightning 2.6's
    ModelCheckpoint(save_last=True) rewrote it only with a new best.) Lightning resumes a
    checkpoint written at a validation's end past that validation, and one written at a batch's
    end at the next batch. The Trainer runs a `Checkpoint` after every other callback: the random
    state saved is the one the next iteration starts from, whatever the others drew."""

    def __init__(self, dirpath: str | Path, every: int = 0):
        self.path = Path(dirpath) / LAST
        self.every = int(every)
        self._signal: int | None = None
        self._previous: dict[int, Any] = {}
        self._saved_at: int | None = None

    # Installed inside fit (after Lightning's SIGTERM connector), restored at teardown.
    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        for signum in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(ValueError):  # not the main thread (a notebook's worker)
                self._previous[signum] = signal.signal(signum, self._on_signal)

    def teardown(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def _on_signal(self, signum: int, frame) -> None:
        if self._signal is not None:  # second Ctrl-C: the user means it
            signal.signal(signum, self._previous.get(signum, signal.SIG_DFL))
            raise KeyboardInterrupt
        self._signal = signum
        log.warning(
            f"{signal.Signals(signum).name} received: finishing the current iteration, then "
            f"writing {self.path} (send it again to abort without saving)"
        )

    def save(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # Every rank takes part; rank 0 writes. weights_only said: Lightning notes it otherwise.
        if trainer.is_global_zero:
            atomic_write(self.path, lambda tmp: trainer.save_checkpoint(tmp, weights_only=False))
        else:
            trainer.save_checkpoint(self.path, weights_only=False)
        trainer.strategy.barrier("last_checkpoint")
        self._saved_at = trainer.global_step

    def _stop_if_signalled(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Save and stop on a signal, the same on every rank (one all-reduce per iteration): a
        signal may reach one rank only, which would wait alone at the save's barrier."""
        signum = self._signal
        if trainer.world_size > 1:
            signum = torch.tensor(signum or 0, device=pl_module.device)
            torch.distributed.all_reduce(signum, op=torch.distributed.ReduceOp.MAX)
            signum = int(signum) or None
        if signum is not None:
            self.save(trainer, pl_module)
            raise TrainingInterrupted(signum, self.path, trainer.global_step)

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        every = trainer.val_check_batch  # validating after this iteration: saved after that
        validates = isinstance(every, int) and trainer.global_step % every == 0
        if trainer.enable_validation and validates:
            return
        self._stop_if_signalled(trainer, pl_module)
        if self.every and trainer.global_step % self.every == 0:
            self.save(trainer, pl_module)

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or trainer.fast_dev_run or trainer.state.fn != "fit":
            return
        self._stop_if_signalled(trainer, pl_module)
        self.save(trainer, pl_module)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # The end of a run that did not end with a validation (limit_val_batches=0, say).
        if not trainer.fast_dev_run and self._saved_at != trainer.global_step:
            self.save(trainer, pl_module)


class BestCheckpoint(ModelCheckpoint):
    """Lean `best-iterNNNNNN.ckpt` (`best-epochNNN.ckpt` before issue 40) of the run's lowest
    validation error, resumes in its folder included (Lightning restores its state there); logs
    a line per validation. A checkpoint resumed in another folder starts a best of its own."""

    def __init__(self, dirpath: str | Path, monitor: str = "val/euler_avg"):
        # No "=" in the name (auto_insert_metric_name): it would not parse as ckpt_path=...
        super().__init__(
            dirpath,
            "best-iter{step:06d}",
            monitor,
            save_weights_only=True,
            auto_insert_metric_name=False,
            save_on_train_epoch_end=False,
        )

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_validation_end(trainer, pl_module)  # saves a new best
        metrics = trainer.callback_metrics
        if trainer.sanity_checking or not trainer.is_global_zero or self.monitor not in metrics:
            return
        best, average = self.best_model_score, float(metrics[self.monitor])
        best = "no best" if best is None else f"best {best:.4f}: {Path(self.best_model_path).name}"
        # Each average with its set where there are two (the module's averages()): an action
        # without training files is in the first, not in the one src.report's verdict judges.
        parts = []
        for name, (_, words) in (pl_module.last_averages or {"average": ([], "")}).items():
            prefix = f"val_euler/{name}/"
            errors = {
                int(k[len(prefix) : -2]): float(v)
                for k, v in metrics.items()
                if k.startswith(prefix)
            }
            # The monitored average is the mean of the first set's horizons, as this is.
            mean = average if name == "average" else sum(errors.values()) / len(errors)
            horizons = ", ".join(f"{ms} ms {v:.3f}" for ms, v in sorted(errors.items()))
            over = f"over {words}: " if words else ""
            parts.append(f"{over}{horizons}; average {mean:.4f}")
        log.info(
            f"validation at iteration {trainer.global_step}: Euler error {parts[0]} ({best})"
            + "".join(f"; {part}" for part in parts[1:])
        )


def upgrade(ckpt: dict) -> dict:
    """A checkpoint of an earlier commit in today's form: hyper-parameters where it has none
    (before f50b604); and of commit a7603dd or before: the module counted its
    iterations in an `iteration` buffer (now the Trainer's global_step; before issue 40 that
    step counted 2 per adversarial iteration, so the buffer is the count) and the data config
    had a `steps_per_epoch` (an epoch was `val_every` iterations)."""
    iteration = ckpt.get("state_dict", {}).pop("iteration", None)
    if iteration is not None:
        ckpt["global_step"] = int(iteration)
    data = ckpt.get("motion", {}).get("config", {}).get("data") or {}
    data.pop("steps_per_epoch", None)
    if "hyper_parameters" not in ckpt and "normalizer.used" in ckpt.get("state_dict", {}):
        ckpt["hyper_parameters"] = _hyperparameters_of(ckpt)
    return ckpt


def _hyperparameters_of(ckpt: dict) -> dict:
    """MotionPredictor's hyper-parameters for a checkpoint written before the module saved its
    own: from the sections and actions it stored, its data config's class and its normaliser."""
    motion, used = ckpt["motion"], ckpt["state_dict"]["normalizer.used"]
    saved = motion["config"]
    data = hydra.utils.get_class(saved["data"]["_target_"])
    facts = {
        "dataset": data.dataset_name,
        "actions": list(motion["actions"]),
        "untrained_actions": motion.get("untrained_actions", []),
        **{k: saved["data"][k] for k in ("observed_len", "future_len")},
        "frame_ms": data.frame_ms,
        "conv_padding": data.conv_padding,
        "used": torch.nonzero(used).flatten().tolist(),
        "num_features": used.numel(),
    }
    sections = ("model", "sampling", "adversarial", "metrics", "compile")
    return {**{k: saved.get(k) for k in sections}, "data": facts}


def read_checkpoint(path: str | Path) -> dict:
    path = Path(path)
    if path.is_dir():  # name the files there: the folder may be a run's or its checkpoints/
        found = sorted(path.glob("*.ckpt")) or sorted(path.glob("checkpoints/*.ckpt"))
        example = " or ".join(map(str, found)) or f"e.g. {path / 'checkpoints' / LAST}"
        raise CheckpointError(f"{path} is a folder; give a checkpoint file: {example}")
    if not path.is_file():
        raise CheckpointError(
            f"checkpoint not found: {path}. Runs keep theirs in "
            "outputs/train/runs/<run>/<time>/checkpoints/ (best-*.ckpt, last.ckpt)."
        )
    try:
        # weights_only: a file from elsewhere cannot run code on load.
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for a damaged file
        raise CheckpointError(
            f"cannot read checkpoint {path}: {_unreadable(path, err)}. Use another checkpoint "
            "of the run (last.ckpt, best-*.ckpt)."
        ) from err
    if not (isinstance(ckpt, dict) and {"motion", "state_dict"} <= ckpt.keys()):
        raise CheckpointError(
            f"{path} is not a checkpoint written by this project's training (no 'motion' "
            "section). Train one with `python -m src.train ...`."
        )
    return upgrade(ckpt)


def _unreadable(path: Path, err: Exception) -> str:
    """Why torch.load failed, in words (torch says a paragraph for a file cut short, a pickle
    opcode for a text file)."""
    with path.open("rb") as f:
        head = f.read(4)
    if not head:
        return "the file is empty"
    if head != b"PK\x03\x04":  # torch.save writes a zip archive
        return "it was not written by torch.save (it is not a zip archive: text, or another format)"
    if not zipfile.is_zipfile(path):
        return (
            "the file is damaged: cut short, the end of its zip archive is missing (as after an "
            "interrupted copy or write)"
        )
    text = " ".join(str(err).split()) or type(err).__name__
    if text.startswith("Weights only load failed"):
        return (
            "it holds Python objects besides tensors and plain containers, which are not "
            "loaded (weights_only: no code from a file runs); this project's checkpoints hold none"
        )
    return f"the file is damaged ({text.split('. ')[0].rstrip('.')})"  # a whole sentence
