"""Training end to end on the synthetic dataset: the CLI smoke run, the generator/discriminator
alternation, checkpoints, TensorBoard curves and evaluation of the checkpoint."""

import copy

import lightning as L
import pytest
import torch

from src.lit.factory import build_datamodule, build_module
from tests.conftest import run_module


def test_cli_fast_dev_run_conv_s2s(tmp_path, synthetic_data_dir):
    proc = run_module(
        "src.train",
        "model=conv_s2s",
        "data=synthetic",
        "debug=fast_dev_run",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]


def _module_and_data(cfg):
    dm = build_datamodule(cfg.data)
    dm.prepare_data()
    dm.setup("fit")
    module = build_module(cfg, dm)
    dm.draws_per_step = 2 if module.adversarial else 1
    return dm, module


def test_alternation_steps_both_optimisers_and_adds_adversarial_term(train_cfg):
    cfg = train_cfg("model=conv_s2s", "adversarial=li2018")
    L.seed_everything(0)
    dm, module = _module_and_data(cfg)
    assert module.adversarial and dm.draws_per_step == 2
    g_before = copy.deepcopy(module.net.state_dict())
    d_before = copy.deepcopy(module.discriminator.state_dict())

    seen = {}

    class Spy(L.Callback):
        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            seen.update({k: v.item() for k, v in trainer.callback_metrics.items()})
            seen["batch"] = batch["observed"].shape[0]

    trainer = L.Trainer(
        max_steps=-1,
        max_epochs=1,
        limit_train_batches=2,
        limit_val_batches=0,
        logger=False,
        enable_checkpointing=False,
        callbacks=[Spy()],
        accelerator="cpu",
        use_distributed_sampler=False,
        enable_progress_bar=False,
    )
    dm.steps_per_epoch = 2
    trainer.fit(module, datamodule=dm)

    changed = lambda a, b: any(not torch.equal(a[k], b[k]) for k in a)  # noqa: E731
    assert changed(g_before, module.net.state_dict()), "generator did not step"
    assert changed(d_before, module.discriminator.state_dict()), "discriminator did not step"
    assert int(module.iteration) == 2
    # Two batches per iteration: one for D (eq. 8), one for G (eq. 9).
    assert seen["batch"] == 2 * cfg.data.batch_size
    expected = seen["train/loss_recon"] + module.lambda_2 * seen["train/loss_l2"]
    expected += module.lambda_adv * seen["train/loss_adv"]
    assert seen["train/loss_g"] == pytest.approx(expected, rel=1e-5)
    assert seen["train/loss_adv"] > 0 and "train/loss_d" in seen


def test_without_regulariser_one_optimiser(train_cfg):
    cfg = train_cfg("model=conv_s2s", "adversarial=none")
    dm, module = _module_and_data(cfg)
    assert not module.adversarial and module.discriminator is None
    optimizers, _ = module.configure_optimizers()
    assert len(optimizers) == 1


@pytest.mark.slow
def test_short_run_checkpoints_logs_and_evaluates(train_cfg, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from src.eval import evaluate
    from src.train import train
    from tests.conftest import compose_config

    cfg = train_cfg("model=conv_s2s", "trainer.log_every_n_steps=1")
    score = train(cfg)
    out = tmp_path / "run"
    assert score == score  # not NaN
    ckpts = sorted(p.name for p in (out / "checkpoints").glob("*.ckpt"))
    assert "last.ckpt" in ckpts and any(n.startswith("best-") for n in ckpts)
    events = EventAccumulator(str(out / "tensorboard")).Reload()
    tags = events.Tags()["scalars"]
    assert "val_euler/walking/0080ms" in tags and "val_euler/average/1000ms" in tags
    assert "train/eta" in tags and "train/loss_d" in tags

    eval_cfg = compose_config(
        "eval",
        [f"ckpt_path={out}/checkpoints/last.ckpt"],
        tmp_path / "eval",
        cfg.paths.data_dir,
    )
    result = evaluate(eval_cfg)
    euler = result["tables"][0]
    assert euler["metric"] == "euler"
    assert (tmp_path / "eval" / "results.md").exists()


@pytest.mark.parametrize(
    "overrides",
    [
        ["model.net.residual=true", "model.net.one_hot=true"],
        ["model.net.residual=false", "model.net.one_hot=false"],
        ["model.net.residual=true", "model.net.one_hot=false", "model.net.tied=false"],
        ["adversarial=li2018"],
    ],
    ids=["res-onehot", "plain-unsup", "res-unsup-untied", "adversarial"],
)
def test_gru_s2s_fast_dev_run(overrides, train_cfg):
    """Martinez's model trains with residual and one-hot on and off, and with the adversarial
    regulariser through the same LightningModule machinery."""
    cfg = train_cfg("model=gru_s2s", "model.net.hidden=16", "debug=fast_dev_run", *overrides)
    from src.train import train

    torch.set_num_threads(1)
    dm, module = _module_and_data(cfg)
    assert module.adversarial == ("adversarial=li2018" in overrides)
    train(cfg)
