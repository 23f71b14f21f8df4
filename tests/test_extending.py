"""docs/extending.md's example: an architecture is one nn.Module file (src/models/residual_mlp.py)
and one model config (conf/model/residual_mlp.yaml); src.train, src.eval, src.visualize,
MotionForecaster, TensorBoard, sweeps and the report then take it unchanged (issue #25)."""

from __future__ import annotations

import contextlib
import io

import pytest
import torch

from src.models.residual_mlp import ResidualMLP
from tests.conftest import ROOT, compose_config, run_module


def test_untrained_residual_mlp_is_zero_velocity():
    net = ResidualMLP(pose_dim=6, num_actions=3, C=4, hidden=8)
    observed = torch.randn(2, 50, 6)
    expected = observed[:, -1:].expand(2, 7, 6)
    torch.testing.assert_close(net(observed, 7), expected, rtol=0, atol=0)


def test_residual_mlp_window_slides_over_ground_truth_or_its_predictions():
    """eta = 0 (teacher forcing, eq. (10)): step k sees the true frames before it; eta = 1: its
    own predictions. Checked against the equation of the module docstring, step by step."""
    torch.manual_seed(0)
    net = ResidualMLP(pose_dim=6, num_actions=3, C=4, hidden=8)
    torch.nn.init.normal_(net.mlp[-1].weight)
    observed, future = torch.randn(2, 50, 6), torch.randn(2, 5, 6)

    def step(window):  # y_k = u_k + W_2 relu(W_1 [u_{k-C+1}; ...; u_k] + b_1) + b_2
        return window[:, -1] + net.mlp(window.flatten(1))

    frames = torch.cat([observed, future], dim=1)
    teacher = net(observed, 5, future=future, eta=0.0)
    for k in range(5):
        torch.testing.assert_close(teacher[:, k], step(frames[:, 50 + k - 4 : 50 + k]))
    free = net(observed, 5)
    window = observed[:, -4:]
    for k in range(5):
        y = step(window)
        torch.testing.assert_close(free[:, k], y)
        window = torch.cat([window[:, 1:], y[:, None]], dim=1)
    assert not torch.allclose(teacher, free)


def test_the_example_model_trains_and_every_command_takes_it(tmp_path, synthetic_data_dir):
    """Trained by src.train on the synthetic data, it beats zero-velocity at every horizon of
    the average row (what it earns its place with); src.eval, src.visualize's windows,
    MotionForecaster and TensorBoard take it with no change to src/lit or the entry points."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from src.eval import evaluate
    from src.inference import MotionForecaster
    from src.plots import window_rows
    from src.results import build_for_evaluation
    from src.train import train
    from src.visualize import select_window

    quiet = ["trainer=cpu", "trainer.enable_progress_bar=false"]
    cfg = compose_config(
        "train",
        ["model=residual_mlp", "data=synthetic", "iterations=100", "val_every=50", *quiet],
        tmp_path / "run",
        synthetic_data_dir,
    )
    assert cfg.adversarial.enabled is False  # the model config chose no regulariser
    train(cfg)
    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"

    def average(*overrides):
        out = tmp_path / f"eval{len(list(tmp_path.glob('eval*')))}"
        eval_cfg = compose_config("eval", [*quiet, *overrides], out, synthetic_data_dir)
        with contextlib.redirect_stdout(io.StringIO()):
            return evaluate(eval_cfg)["tables"][0]["average"]["values"]

    ours = average(f"ckpt_path={ckpt}")
    zero_velocity = average("model=zero_velocity", "data=synthetic")
    assert all(ours[ms] < zero_velocity[ms] for ms in zero_velocity), (ours, zero_velocity)

    tags = EventAccumulator(str(tmp_path / "run" / "tensorboard")).Reload().Tags()["scalars"]
    assert "val_euler/walking/1000ms" in tags and "train/loss_recon" in tags

    vis_cfg = compose_config(
        "visualize", [f"ckpt_path={ckpt}"], tmp_path / "vis", synthetic_data_dir
    )
    dm, module = build_for_evaluation(vis_cfg)
    rows, _, _ = window_rows(dm, module, select_window(dm, "walking", 0))
    labels = [row.label for row in rows]
    assert labels == ["prediction (residual_mlp)", "ground truth", "zero-velocity"]

    forecaster = MotionForecaster.from_checkpoint(ckpt)
    frames = dm.raw_window(0)
    assert forecaster.predict(frames[:50]).shape == (25, 99)


@pytest.mark.slow
def test_the_example_model_in_a_sweep_and_the_report(tmp_path, synthetic_data_dir):
    from src.report import main as report

    proc = run_module(
        "src.train",
        "hydra.mode=MULTIRUN",
        "model=residual_mlp",
        "model.net.hidden=16,32",
        "data=synthetic",
        "iterations=2",
        "val_every=2",
        "trainer.accelerator=cpu",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    (sweep,) = (tmp_path / "train" / "multiruns").iterdir()
    from tests.conftest import compose_config

    out = tmp_path / "results.md"
    args = [f"runs=[{sweep}]", f"out={out}", "protocols=[srnn]", "datasets=[]"]
    assert report(compose_config("report", args, tmp_path / "work")) == 0
    labels = [
        line.split("|")[1].strip().rstrip("⁰¹²³⁴⁵⁶⁷⁸⁹")  # a footnote gives the settings
        for line in out.read_text().splitlines()
        if "| ours, best " in line
    ]
    # Two experiments (one per hidden size), each under its short label.
    assert labels == ["residual_mlp_synthetic, hidden=16", "residual_mlp_synthetic, hidden=32"]


def _plain_trainer_script() -> str:
    text = (ROOT / "docs" / "extending.md").read_text()
    block = text.split("<!-- plain-trainer:start -->")[1].split("<!-- plain-trainer:end -->")[0]
    return block.split("```python\n")[1].split("```")[0]


@pytest.mark.slow
def test_the_plain_trainer_script_trains_as_src_train(tmp_path, synthetic_data_dir):
    """docs/extending.md's script (at most 20 lines: compose, instantiate, a plain L.Trainer)
    gives src.train's losses at every one of the 40 iterations, at the same seed (one thread)."""
    import csv
    import os
    import subprocess
    import sys

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    script = _plain_trainer_script()
    assert len(script.strip().splitlines()) <= 20
    env = {**os.environ, "MOTION_DATA_DIR": str(synthetic_data_dir), "OMP_NUM_THREADS": "1",
           "PYTHONPATH": str(ROOT)}  # fmt: skip
    plain = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=900)  # fmt: skip
    assert plain.returncode == 0, plain.stderr[-3000:]
    train = [sys.executable, "-m", "src.train", "data=synthetic", "iterations=40", "val_every=20",
             "trainer.log_every_n_steps=1", "trainer.enable_progress_bar=false",
             f"paths.log_dir={tmp_path / 'logs'}"]  # fmt: skip
    proc = subprocess.run(train, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]

    (metrics,) = (tmp_path / "outputs" / "plain").rglob("metrics.csv")
    ours = {}
    for row in csv.DictReader(metrics.open()):
        if row.get("train/loss_g"):
            ours[int(row["step"])] = float(row["train/loss_g"])
    (events,) = {p.parent for p in (tmp_path / "logs").rglob("events.out.tfevents.*")}
    theirs = {e.step: e.value for e in EventAccumulator(str(events)).Reload().Scalars(
        "train/loss_g")}  # fmt: skip
    assert sorted(ours) == sorted(theirs) == list(range(40))
    for step, value in theirs.items():
        assert ours[step] == pytest.approx(value, rel=1e-6, abs=1e-7), step
