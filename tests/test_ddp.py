"""DDP on the CPU (gloo, 2 processes) through the CLI, with the adversarial model's manual
optimisation: the run must finish, and the validation error it logged must equal a
single-process evaluation of its checkpoint. The evaluation loader is not split across ranks,
so every rank evaluates every window; the metrics' summed states then count each window twice,
which leaves their mean unchanged."""

from __future__ import annotations

import lightning as L
import pytest
from omegaconf import OmegaConf

from src.eval import load_for_eval
from tests.conftest import compose_config, run_module


@pytest.mark.slow
def test_ddp_two_cpu_processes_match_single_process_evaluation(tmp_path, synthetic_data_dir):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    proc = run_module(
        "src.train",
        "trainer=ddp",
        "data=synthetic",
        "model=conv_s2s",
        "adversarial=li2018",
        "model.net.nf=2",
        "data.batch_size=4",
        "trainer.accelerator=cpu",
        "trainer.devices=2",
        "iterations=2",
        "val_every=2",
        "trainer.enable_progress_bar=false",
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
    dm, module, _, _ = load_for_eval(cfg)
    trainer = L.Trainer(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False)
    trainer.validate(module, datamodule=dm, verbose=False)
    for tag, value in logged.items():
        assert float(trainer.callback_metrics[tag]) == pytest.approx(value, rel=1e-5), tag
