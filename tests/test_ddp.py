"""DDP on the CPU (gloo, 2 processes) through the CLI, with the adversarial model's manual
optimisation: the run must finish, and the validation error it logged must equal a
single-process evaluation of its checkpoint. The evaluation loader is not split across ranks,
so every rank evaluates every window; the metrics' summed states then count each window twice,
which leaves their mean unchanged."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import lightning as L
import pytest
import torch
from omegaconf import OmegaConf

from src.results import build_for_evaluation
from tests.conftest import ROOT, compose_config, run_module

TINY_DDP = [
    "trainer=ddp",
    "data=synthetic",
    "model=conv_s2s",
    "adversarial=li2018",
    "model.net.nf=2",
    "data.batch_size=4",
    "trainer.accelerator=cpu",
    "trainer.devices=2",
    "trainer.enable_progress_bar=false",
]


@pytest.mark.slow
def test_ddp_two_cpu_processes_match_single_process_evaluation(tmp_path, synthetic_data_dir):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    proc = run_module(
        "src.train",
        *TINY_DDP,
        "iterations=2",
        "val_every=2",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path / "logs",
        timeout=400,
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output[-3000:]
    assert "MEMBER: 2/2" in output, "Lightning did not start a second process"
    (summary_path,) = (tmp_path / "logs" / "train" / "runs").glob("*/*/summary.yaml")
    run = summary_path.parent
    summary = OmegaConf.load(summary_path)
    assert summary.iterations == 2

    events = EventAccumulator(str(run / "tensorboard")).Reload()
    logged = {tag: events.Scalars(tag)[-1].value for tag in ("val/euler_avg", "val/mpjpe_avg")}
    assert logged["val/euler_avg"] == pytest.approx(summary.best_val_euler_avg, rel=1e-6)

    cfg = compose_config(
        "eval",
        [f"ckpt_path={run / 'checkpoints' / 'last.ckpt'}", "trainer.accelerator=cpu"],
        tmp_path / "eval",
        synthetic_data_dir,
    )
    dm, module = build_for_evaluation(cfg)
    trainer = L.Trainer(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False)
    trainer.validate(module, datamodule=dm, verbose=False)
    for tag, value in logged.items():
        assert float(trainer.callback_metrics[tag]) == pytest.approx(value, rel=1e-5), tag


SIGTERM_TO_RANK_0 = """
# Test hook loaded through PYTHONPATH: SIGTERM reaches rank 0 alone (`kill <pid>` of the
# command a user started) while its third iteration runs; rank 1 never receives it.
import os
import signal

from src.lit.predictor import MotionPredictor

_step = MotionPredictor.training_step


def _step_with_sigterm(self, batch, batch_idx):
    if self.global_rank == 0 and self.global_step == 2:
        os.kill(os.getpid(), signal.SIGTERM)
    return _step(self, batch, batch_idx)


MotionPredictor.training_step = _step_with_sigterm
"""


@pytest.mark.slow
def test_sigterm_to_one_rank_stops_every_rank_with_a_resumable_checkpoint(
    tmp_path, synthetic_data_dir
):
    """The interrupt flag is per process: a rank that stopped to save alone would wait at the
    save's barrier while the others trained on (a hang). Every rank must stop after the same
    iteration, last.ckpt must hold it, and the run must resume from it to its end."""
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(SIGTERM_TO_RANK_0)
    log_dir = tmp_path / "logs"
    env = {
        **os.environ,
        "MOTION_DATA_DIR": str(synthetic_data_dir),
        "PYTHONUNBUFFERED": "1",
        "PYTHONPATH": os.pathsep.join([str(hook), str(ROOT)]),
    }
    # A small discriminator too: two DDP runs in one test.
    length = [
        "adversarial.discriminator.nf=2",
        "adversarial.discriminator.d_z=8",
        "adversarial.discriminator.d_fc=8",
        "iterations=6",
        "val_every=6",
        "checkpoint_every=0",
    ]
    # A session of its own: the ranks form one process group, which must be empty at the end.
    proc = subprocess.Popen(
        [sys.executable, "-m", "src.train", f"paths.log_dir={log_dir}", *TINY_DDP, *length],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        out, _ = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail("the DDP run hung after SIGTERM:\n" + out[-3000:])
    deadline = time.monotonic() + 60
    while True:  # rank 1 is rank 0's child: it must be gone too
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        if time.monotonic() > deadline:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail("a rank was still running after rank 0 exited:\n" + out[-3000:])
        time.sleep(0.2)
    assert "MEMBER: 2/2" in out, "Lightning did not start a second process"
    assert proc.returncode == 128 + signal.SIGTERM, out[-3000:]
    (run,) = (log_dir / "train" / "runs").glob("*/*")
    last = run / "checkpoints" / "last.ckpt"
    # Both ranks stopped after iteration 3 and said so, rank 1 included.
    assert out.count(f"stopped after iteration 3 and wrote {last}") == 2, out[-3000:]
    assert torch.load(last, weights_only=True)["global_step"] == 3
    assert not (run / "summary.yaml").exists()

    time.sleep(1.1)  # run folders are timestamped to the second
    resumed = run_module(
        "src.train",
        *TINY_DDP,
        *length,
        f"ckpt_path={last}",
        data_dir=synthetic_data_dir,
        log_dir=log_dir,
        timeout=400,
    )
    assert resumed.returncode == 0, (resumed.stdout + resumed.stderr)[-3000:]
    # Every rank continued in the run's own folder.
    assert list((log_dir / "train" / "runs").glob("*/*")) == [run]
    assert OmegaConf.load(run / "summary.yaml").iterations == 6
