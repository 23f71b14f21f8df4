"""Checkpoints never lose work: last.ckpt is the last iteration whatever validation did, saves
are atomic, the best checkpoint is lean and stays the best of the whole run across resumes."""

from __future__ import annotations

import os
import signal

import pytest
import torch
from omegaconf import OmegaConf

from src.build import require_resumable
from src.inference import MotionForecaster
from src.lit.checkpoints import (
    LAST,
    CheckpointError,
    LastCheckpoint,
    read_checkpoint,
)
from src.lit.predictor import MotionPredictor
from src.prepare import compose_config
from src.train import train
from tests.objects import QUIET, TINY_CONV

TINY = ["data=synthetic", *QUIET, *TINY_CONV]


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def rising_error(monkeypatch):
    """Validation error that only gets worse: 1, 2, 3, ... per validation, so only the first
    validation is ever an improvement (the case where Lightning kept an old last.ckpt)."""
    original = MotionPredictor.log_dict

    def rising(self, metrics, **kwargs):
        if "val/euler_avg" in metrics:
            metrics = {**metrics, "val/euler_avg": float(self.global_step)}
        return original(self, metrics, **kwargs)

    monkeypatch.setattr(MotionPredictor, "log_dict", rising)


@pytest.fixture
def falling_error(monkeypatch):
    """Validation error that only gets better: 100 - iteration, so every validation is a new
    best and Lightning removes the best file it replaces."""
    original = MotionPredictor.log_dict

    def falling(self, metrics, **kwargs):
        if "val/euler_avg" in metrics:
            metrics = {**metrics, "val/euler_avg": 100.0 - float(self.global_step)}
        return original(self, metrics, **kwargs)

    monkeypatch.setattr(MotionPredictor, "log_dict", falling)


@pytest.fixture
def best_at_the_second_validation(monkeypatch):
    """Validation errors 5, 1, 3 at iterations 2, 4, 6: the best is the second validation."""
    original = MotionPredictor.log_dict
    errors = {2: 5.0, 4: 1.0, 6: 3.0}

    def scripted(self, metrics, **kwargs):
        if "val/euler_avg" in metrics:
            metrics = {**metrics, "val/euler_avg": errors[self.global_step]}
        return original(self, metrics, **kwargs)

    monkeypatch.setattr(MotionPredictor, "log_dict", scripted)


def _run(out, data_dir, *overrides):
    cfg = compose_config("train", [*TINY, *overrides], out, data_dir)
    score = train(cfg)
    return score, OmegaConf.to_container(OmegaConf.load(out / "summary.yaml"))


def _load(path):
    return torch.load(path, map_location="cpu", weights_only=True)


def test_last_ckpt_is_the_last_iteration_when_the_error_rises(
    rising_error, tmp_path, synthetic_data_dir
):
    out = tmp_path / "run"
    score, summary = _run(out, synthetic_data_dir, "iterations=8", "val_every=2")
    last = _load(out / "checkpoints" / LAST)
    assert last["global_step"] == 8
    # The best is the first validation (iteration 2), kept lean beside it.
    (best,) = (out / "checkpoints").glob("best-*.ckpt")
    assert best.name == "best-iter000002.ckpt"  # named by its iteration
    assert _load(best)["global_step"] == 2
    assert score == summary["best_val_euler_avg"] == 2.0
    assert summary["best_checkpoint"] == str(best) and summary["last_checkpoint"] == str(
        out / "checkpoints" / LAST
    )


def test_checkpoint_every_writes_last_between_validations(tmp_path, synthetic_data_dir):
    seen = []
    original = LastCheckpoint.save

    def spy(self, trainer, pl_module):
        seen.append(pl_module.global_step)
        original(self, trainer, pl_module)

    mp = pytest.MonkeyPatch()
    mp.setattr(LastCheckpoint, "save", spy)
    try:
        _run(tmp_path / "run", synthetic_data_dir, "iterations=6", "val_every=6",
             "checkpoint_every=2")  # fmt: skip
    finally:
        mp.undo()
    # 6 once: the epoch's last iteration is saved after its validation, not before it.
    assert seen == [2, 4, 6]


def test_last_ckpt_holds_the_final_validation_when_checkpoint_every_divides_val_every(
    best_at_the_second_validation, tmp_path, synthetic_data_dir
):
    """The periodic save at an epoch's last iteration came before that epoch's validation, and
    the save after the validation was skipped as a second one at the same iteration: last.ckpt
    then forgot the validation's best, and a resume that trained longer replaced it by a worse
    one."""
    first = tmp_path / "first"
    _run(first, synthetic_data_dir, "iterations=4", "val_every=2", "checkpoint_every=2")
    best_first = first / "checkpoints" / "best-iter000004.ckpt"
    last = _load(first / "checkpoints" / LAST)
    (best_state,) = [s for s in last["callbacks"].values() if "best_model_score" in s]
    assert float(best_state["best_model_score"]) == 1.0
    assert best_state["best_model_path"] == str(best_first)

    score, summary = _run(  # resumed in its folder
        first,
        synthetic_data_dir,
        "iterations=6",
        "val_every=2",
        "checkpoint_every=2",
        f"ckpt_path={first / 'checkpoints' / LAST}",
    )
    assert score == 1.0 and summary["best_checkpoint"] == str(best_first)
    assert list((first / "checkpoints").glob("best-*.ckpt")) == [best_first]


def test_best_checkpoint_is_lean_and_loads_for_eval_and_inference(tmp_path, synthetic_data_dir):
    """Real model sizes (conv_s2s + discriminator on the H3.6M shape of the synthetic data)."""
    out = tmp_path / "run"
    _run(
        out,
        synthetic_data_dir,
        "model.net.nf=16",
        "model.net.d_z=512",
        "adversarial.discriminator.nf=32",
        "adversarial.discriminator.d_z=512",
        "adversarial.discriminator.d_fc=256",
        "data.batch_size=2",
        "iterations=1",
        "val_every=1",
    )
    (best,) = (out / "checkpoints").glob("best-*.ckpt")
    last = out / "checkpoints" / LAST
    ratio = best.stat().st_size / last.stat().st_size
    assert ratio <= 0.40, f"best is {ratio:.0%} of last.ckpt"
    ckpt = read_checkpoint(best)
    assert "optimizer_states" not in ckpt and "motion" in ckpt
    with pytest.raises(CheckpointError, match="resume from the run's last.ckpt"):
        require_resumable(ckpt, best)
    require_resumable(read_checkpoint(last), last)

    forecaster = MotionForecaster.from_checkpoint(best)
    frames = torch.zeros(1, 50, 99).numpy()
    assert forecaster.predict(frames, future_len=5).shape == (1, 5, 99)

    from src.eval import evaluate

    cfg = compose_config("eval", [f"ckpt_path={best}"], tmp_path / "eval", synthetic_data_dir)
    results = evaluate(cfg)
    assert results  # evaluated the lean checkpoint end to end


def test_last_checkpoint_write_is_atomic_inside_training(
    rising_error, tmp_path, synthetic_data_dir, monkeypatch
):
    """The callback writes beside last.ckpt and renames: a crash in the write of the second
    validation's checkpoint leaves the first one loadable."""
    calls = []
    original = LastCheckpoint.save

    def crash_on_second(self, trainer, pl_module):
        calls.append(1)
        if len(calls) == 2:
            real = trainer.save_checkpoint

            def half(path, *a, **k):
                real(path, *a, **k)
                with open(path, "r+b") as f:  # truncate what was written: a kill mid-write
                    f.truncate(100)
                raise OSError("killed mid-write")

            monkeypatch.setattr(trainer, "save_checkpoint", half)
        original(self, trainer, pl_module)

    monkeypatch.setattr(LastCheckpoint, "save", crash_on_second)
    out = tmp_path / "run"
    cfg = compose_config("train", [*TINY, "iterations=4", "val_every=2"], out, synthetic_data_dir)
    with pytest.raises(OSError, match="killed mid-write"):
        train(cfg)
    assert read_checkpoint(out / "checkpoints" / LAST)["global_step"] == 2


def test_best_survives_a_resume(rising_error, tmp_path, synthetic_data_dir):
    """Resumed in its folder, the run's first validation after the resume is worse than the best
    before it: no new best file, and the summary names the earlier one."""
    run = tmp_path / "run"
    _run(run, synthetic_data_dir, "iterations=4", "val_every=2")
    (best_first,) = (run / "checkpoints").glob("best-*.ckpt")

    score, summary = _run(
        run, synthetic_data_dir, "iterations=8", "val_every=2",
        f"ckpt_path={run / 'checkpoints' / LAST}",
    )  # fmt: skip
    assert list((run / "checkpoints").glob("best-*.ckpt")) == [best_first]
    assert summary["best_checkpoint"] == str(best_first) and score == 2.0
    assert _load(run / "checkpoints" / LAST)["global_step"] == 8


def test_a_better_best_after_a_resume_replaces_the_earlier_one_as_within_a_run(
    falling_error, tmp_path, synthetic_data_dir
):
    """Resumed in its folder, a better validation replaces the best file as it would have
    without the resume; resumed from a copy into another folder, the run's own folder keeps
    every file, and the best is of the folder trained into."""
    run = tmp_path / "run"
    _run(run, synthetic_data_dir, "iterations=4", "val_every=2")
    before = {p.name: p.read_bytes() for p in (run / "checkpoints").iterdir()}
    assert "best-iter000004.ckpt" in before
    copy = tmp_path / "copy.ckpt"
    copy.write_bytes(before[LAST])

    score, summary = _run(
        tmp_path / "elsewhere", synthetic_data_dir, "iterations=8", "val_every=2",
        f"ckpt_path={copy}",
    )  # fmt: skip
    assert {p.name: p.read_bytes() for p in (run / "checkpoints").iterdir()} == before
    (best,) = (tmp_path / "elsewhere" / "checkpoints").glob("best-*.ckpt")
    assert best.name == "best-iter000008.ckpt" and summary["best_checkpoint"] == str(best)

    score, summary = _run(
        run, synthetic_data_dir, "iterations=8", "val_every=2",
        f"ckpt_path={run / 'checkpoints' / LAST}",
    )  # fmt: skip
    (best,) = (run / "checkpoints").glob("best-*.ckpt")
    assert best.name == "best-iter000008.ckpt" and score == 92.0
    assert summary["best_checkpoint"] == str(best)


def test_each_validation_logs_one_line_with_the_best_so_far(
    rising_error, tmp_path, synthetic_data_dir, caplog
):
    """The validation error was printed nowhere but TensorBoard: one line per validation
    names the iteration, the average error at each horizon, the average and the best so far."""
    with caplog.at_level("INFO", logger="src.lit.checkpoints"):
        _run(tmp_path / "run", synthetic_data_dir, "iterations=4", "val_every=2")
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("validation")]
    assert len(lines) == 2
    assert lines[0].startswith("validation at iteration 2: Euler error 80 ms ")
    assert ", 1000 ms " in lines[0]
    assert lines[0].endswith("; average 2.0000 (best 2.0000: best-iter000002.ckpt)")
    assert lines[1].endswith("; average 4.0000 (best 2.0000: best-iter000002.ckpt)")


def test_a_best_checkpoint_of_the_earlier_naming_carries_over_a_resume(
    rising_error, tmp_path, synthetic_data_dir
):
    """Runs of earlier versions named the best file by Lightning's epoch (best-epoch000.ckpt):
    resuming such a run keeps it as the best, and it loads for evaluation."""

    first = tmp_path / "first"
    _run(first, synthetic_data_dir, "iterations=2", "val_every=2")
    (best,) = (first / "checkpoints").glob("best-*.ckpt")
    old = best.rename(best.with_name("best-epoch000.ckpt"))
    last = _load(first / "checkpoints" / LAST)  # as the earlier version wrote it
    (state,) = [s for s in last["callbacks"].values() if "best_model_path" in s]
    state["best_model_path"] = str(old)
    torch.save(last, first / "checkpoints" / LAST)

    score, summary = _run(
        first, synthetic_data_dir, "iterations=4", "val_every=2",
        f"ckpt_path={first / 'checkpoints' / LAST}",
    )  # fmt: skip
    assert summary["best_checkpoint"] == str(old) and score == 2.0
    assert read_checkpoint(summary["best_checkpoint"])["global_step"] == 2


def test_resuming_from_a_lean_best_checkpoint_is_refused(tmp_path, synthetic_data_dir):
    first = tmp_path / "first"
    _run(first, synthetic_data_dir, "iterations=2", "val_every=2")
    (best,) = (first / "checkpoints").glob("best-*.ckpt")
    cfg = compose_config(
        "train", [*TINY, "iterations=4", "val_every=2", f"ckpt_path={best}"],
        tmp_path / "second", synthetic_data_dir,
    )  # fmt: skip
    with pytest.raises(CheckpointError, match="weights only"):
        train(cfg)


def test_a_second_signal_aborts_at_once(tmp_path):
    """The first SIGINT/SIGTERM only asks for a save after the iteration in progress; a second
    one means it: KeyboardInterrupt at once, with the handler from before the run back."""
    before = signal.getsignal(signal.SIGTERM)
    last = LastCheckpoint(tmp_path)
    last.on_train_start(None, None)
    try:
        assert signal.getsignal(signal.SIGTERM) == last._on_signal  # or SIGTERM ends pytest
        os.kill(os.getpid(), signal.SIGTERM)
        assert last._signal == signal.SIGTERM
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
        assert signal.getsignal(signal.SIGTERM) is before
    finally:
        last.teardown(None, None, "fit")
    assert signal.getsignal(signal.SIGTERM) is before


def test_cuda_random_state_is_saved_and_restored(train_cfg):
    """On a GPU, dropout masks come from the CUDA generator: a resume restores it too."""
    if not torch.cuda.is_available():
        pytest.skip("needs CUDA (the CPU generator's round trip is in tests/test_resume.py)")
    from src.build import build_datamodule, build_module

    cfg = train_cfg(*TINY[1:])
    dm = build_datamodule(cfg.data)
    dm.prepare_data()
    dm.setup("fit")
    module = build_module(cfg, dm).cuda()
    torch.cuda.manual_seed_all(7)
    ckpt: dict = {}
    module.on_save_checkpoint(ckpt)
    assert len(ckpt["rng"]["cuda"]) == torch.cuda.device_count()
    expected = torch.rand(4, device="cuda")
    torch.rand(100, device="cuda")  # move the generator on, as training would
    module.on_load_checkpoint(ckpt)
    assert torch.equal(torch.rand(4, device="cuda"), expected)


def _as_a7603dd_wrote(path, out, iteration=None):
    """The checkpoint at `path` in the form of commit a7603dd (the 20,000-iteration runs of
    docs/runs): the module's `iteration` buffer, and an epoch length in the data config."""
    ckpt = _load(path)
    step = ckpt["global_step"] if iteration is None else iteration
    ckpt["state_dict"]["iteration"] = torch.tensor(step)
    ckpt["motion"]["config"]["data"]["steps_per_epoch"] = 2
    torch.save(ckpt, out)
    return out


def test_a_checkpoint_of_commit_a7603dd_evaluates_to_the_same_numbers(tmp_path, synthetic_data_dir):
    from src.eval import evaluate

    out = tmp_path / "run"
    _run(out, synthetic_data_dir, "iterations=2", "val_every=2")
    (best,) = (out / "checkpoints").glob("best-*.ckpt")
    old = _as_a7603dd_wrote(best, tmp_path / "old.ckpt")

    def errors(path):
        cfg = compose_config(
            "eval", [f"ckpt_path={path}"], tmp_path / path.stem, synthetic_data_dir
        )
        return {k: v for k, v in evaluate(cfg).items() if k != "provenance"}

    assert errors(old) == errors(best)
    assert read_checkpoint(old)["global_step"] == 2
    # Before issue 40 the Trainer counted 2 steps per adversarial iteration: the buffer counts.
    doubled = _as_a7603dd_wrote(best, tmp_path / "doubled.ckpt", iteration=1)
    assert read_checkpoint(doubled)["global_step"] == 1
