"""Training end to end on the synthetic dataset: the CLI smoke run, the generator/discriminator
alternation, checkpoints, TensorBoard curves and evaluation of the checkpoint."""

import copy

import hydra
import lightning as L
import pandas as pd
import pytest
import torch
import yaml

from src.build import build_datamodule, build_module
from tests.conftest import run_module
from tests.objects import TINY_CONV


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
    return dm, build_module(cfg, dm)


def test_alternation_steps_both_optimisers_and_adds_adversarial_term(train_cfg):
    cfg = train_cfg("model=conv_s2s", "adversarial=li2018")
    L.seed_everything(0)
    dm, module = _module_and_data(cfg)
    assert module.adversarial
    g_before = copy.deepcopy(module.net.state_dict())
    d_before = copy.deepcopy(module.discriminator.state_dict())

    seen = {}

    class Spy(L.Callback):
        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            seen.update({k: v.item() for k, v in trainer.callback_metrics.items()})
            seen["batch"] = (batch["d"]["observed"].shape[0], batch["observed"].shape[0])

    trainer = L.Trainer(
        max_steps=2,
        limit_val_batches=0,
        logger=False,
        enable_checkpointing=False,
        callbacks=[Spy()],
        accelerator="cpu",
        use_distributed_sampler=False,
        enable_progress_bar=False,
        log_every_n_steps=2,
    )
    trainer.fit(module, datamodule=dm)

    changed = lambda a, b: any(not torch.equal(a[k], b[k]) for k in a)  # noqa: E731
    assert changed(g_before, module.net.state_dict()), "generator did not step"
    assert changed(d_before, module.discriminator.state_dict()), "discriminator did not step"
    assert trainer.global_step == 2
    # Two batches per iteration: one for D (eq. 8), one for G (eq. 9).
    assert seen["batch"] == (cfg.data.batch_size, cfg.data.batch_size)
    expected = seen["train/loss_recon"] + module.lambda_2 * seen["train/loss_l2"]
    expected += module.lambda_adv * seen["train/loss_adv"]
    assert seen["train/loss_g"] == pytest.approx(expected, rel=1e-5)
    assert seen["train/loss_adv"] > 0 and "train/loss_d" in seen
    # The progress bar's loss, a host number refreshed on the iterations whose losses are logged.
    bar = trainer.progress_bar_metrics["train/loss_recon_bar"]
    assert bar == pytest.approx(seen["train/loss_recon"])


def _gradients_of_one_step(module, batch, lambda_2, lambda_2_d):
    """The gradients each optimiser would step with in one training_step (weights unchanged),
    with the Lightning hooks it calls bound to plain PyTorch."""
    module.lambda_2, module.lambda_2_d = lambda_2, lambda_2_d
    opts, _ = module.configure_optimizers()
    seen = {}
    for name, opt, net in zip("gd", opts, (module.net, module.discriminator), strict=True):
        opt.step = lambda net=net, name=name: seen.update(
            {f"{name}.{k}": p.grad.clone() for k, p in net.named_parameters()}
        )
    module.optimizers, module.lr_schedulers = (lambda: opts), (lambda: [])
    module.toggle_optimizer = module.untoggle_optimizer = lambda opt: None
    module.manual_backward = lambda loss: loss.backward()
    module.log = module.log_dict = lambda *a, **k: None
    torch.manual_seed(0)  # the same dropout masks in every call
    module.training_step(batch, 0)
    return seen


def test_l2_terms_reach_the_gradients_as_lambda_times_weight(train_cfg):
    """The L2 terms of eq. (9) (generator) and of the discriminator's objective are added to the
    gradients in closed form (add_l2_gradient_) instead of being backpropagated: the step
    with them must see exactly lambda * w more on every weight tensor, and nothing on biases."""
    cfg = train_cfg("model=conv_s2s", "adversarial=li2018")
    dm, module = _module_and_data(cfg)
    module.train()
    batch = next(iter(dm.train_dataloader()))
    lam_g, lam_d = 1e-2, 3e-2
    without = _gradients_of_one_step(module, batch, 0.0, 0.0)
    with_l2 = _gradients_of_one_step(module, batch, lam_g, lam_d)
    params = {f"g.{k}": p for k, p in module.net.named_parameters()}
    params |= {f"d.{k}": p for k, p in module.discriminator.named_parameters()}
    assert set(without) == set(with_l2) == set(params)
    for key, p in params.items():
        lam = (lam_g if key.startswith("g.") else lam_d) if p.ndim > 1 else 0.0
        expected = without[key] + lam * p.detach()
        torch.testing.assert_close(with_l2[key], expected, rtol=1e-5, atol=1e-8, msg=key)
        if lam:  # the term is large enough that leaving it out would fail the check above
            assert (lam * p.detach()).abs().max() > 10 * (1e-5 * expected.abs().max() + 1e-8)


def test_l2_gradient_is_the_gradient_of_the_logged_penalty():
    """add_l2_gradient_ against autograd through sum(w^2)/2 over weight tensors, the value
    l2_penalty logs (TF's l2_regularizer, protocol 6.6)."""
    from src.lit.predictor import add_l2_gradient_, l2_penalty
    from src.models.conv_encoder import ConvEncoder

    torch.manual_seed(0)
    net = ConvEncoder(20, 54, d_out=32, nf=4).eval()
    x = torch.randn(3, 20, 54)
    weights = [p for p in net.parameters() if p.ndim > 1]
    penalty = sum(p.pow(2).sum() / 2 for p in weights)
    assert l2_penalty(net).item() == pytest.approx(penalty.item(), rel=1e-6)
    (net(x).square().mean() + 0.5 * penalty).backward()
    expected = [p.grad.clone() for p in net.parameters()]
    net.zero_grad()
    net(x).square().mean().backward()
    add_l2_gradient_(net, 0.5)
    for got, want in zip((p.grad for p in net.parameters()), expected, strict=True):
        torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-9)


def test_float16_gradient_scaling_is_refused(train_cfg):
    """The L2 gradient is added after backward: scaled (16-mixed) gradients would shrink it."""
    from types import SimpleNamespace

    _, module = _module_and_data(train_cfg("model=conv_s2s"))
    module._trainer = SimpleNamespace(precision_plugin=SimpleNamespace(scaler=object()))
    with pytest.raises(ValueError, match="16-mixed"):
        module.on_fit_start()


def test_without_regulariser_one_optimiser(train_cfg):
    cfg = train_cfg("model=conv_s2s", "adversarial=none")
    dm, module = _module_and_data(cfg)
    assert not module.adversarial and module.discriminator is None
    optimizers, _ = module.configure_optimizers()
    assert len(optimizers) == 1


@pytest.mark.slow
def test_short_run_checkpoints_logs_and_evaluates(train_cfg, tmp_path, capsys):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from src.eval import evaluate
    from src.reporting.runs import validation_curve
    from src.train import train
    from tests.conftest import compose_config

    cfg = train_cfg("model=conv_s2s", "trainer.log_every_n_steps=1", "sampling=linear")
    score = train(cfg)
    # The bar counts iterations, not the schedule's one endless epoch ("Epoch 0/-2").
    bar = capsys.readouterr().out
    assert "iterations" in bar and "4/4" in bar and "Epoch" not in bar
    out = tmp_path / "run"
    assert score == score  # not NaN
    ckpts = sorted(p.name for p in (out / "checkpoints").glob("*.ckpt"))
    assert "last.ckpt" in ckpts and any(n.startswith("best-") for n in ckpts)
    events = EventAccumulator(str(out / "tensorboard")).Reload()
    tags = events.Tags()["scalars"]
    assert "val_euler/walking/0080ms" in tags and "val_euler/average/1000ms" in tags
    assert "train/eta" in tags and "train/loss_d" in tags
    # Numbers logged from the host (eta, learning rates) arrive as they were.
    schedule = hydra.utils.instantiate(cfg.sampling)
    etas = events.Scalars("train/eta")
    assert len(etas) == cfg.iterations
    for event in etas:  # the logger's step is the iteration the value was used at
        assert event.value == pytest.approx(schedule(event.step), abs=1e-7)
    assert [e.value for e in events.Scalars("train/lr")] == pytest.approx(
        [cfg.model.optimizer.lr] * len(events.Scalars("train/lr"))
    )
    # src.report's reading of the validations: after 2 and 4 iterations (val_every=2), each
    # horizon's average; their mean at the end is the summary's final error.
    curve = validation_curve(out)
    logged = {int(t[-6:-2]) for t in tags if t.startswith("val_euler/average/")}
    assert list(curve) == [2, 4] and set(curve[4]) == logged and logged
    summary = yaml.safe_load((out / "summary.yaml").read_text())
    final = sum(curve[4].values()) / len(curve[4])
    assert final == pytest.approx(summary["final_val_euler_avg"], rel=1e-5)

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
    # Its long rows say whose checkpoint: the run's seed and the iterations it had trained.
    rows = pd.read_csv(tmp_path / "eval" / "results_long.csv")
    assert set(rows.seed) == {cfg.seed} and set(rows.iterations) == {cfg.iterations}


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


def test_evaluation_is_float32_under_bf16_autocast(train_cfg):
    """trainer.precision=bf16-mixed trains under autocast, and Lightning also wraps validation
    in it; the reported errors must be the float32 ones (bf16 moved them by up to 0.006 rad)."""
    cfg = train_cfg("model=conv_s2s")
    dm, module = _module_and_data(cfg)
    module.eval()
    torch.manual_seed(0)
    with torch.no_grad():  # some weights far from zero, so rounding would show
        for p in module.net.parameters():
            p.mul_(4)
    batch = next(iter(dm.val_dataloader()))
    errors = []
    for bf16 in (False, True):
        with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            module.validation_step(batch, 0)
        errors.append(torch.nan_to_num(module.euler.compute(), nan=-1.0))
        module.euler.reset()
        module.mpjpe.reset()
    assert (errors[0] > 0).any()
    assert torch.equal(errors[0], errors[1])


TINY_ADV = [*TINY_CONV, "media_every=0", "trainer.enable_progress_bar=false"]


class _Batches(L.Callback):
    """Records the training batches a fit hands to the module."""

    def __init__(self):
        self.seen = []

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        self.seen.append((batch["d"]["observed"].clone(), batch["observed"].clone()))


def _plain_fit(cfg, **trainer_kwargs):
    """The ordinary Lightning pattern: the factory's module and datamodule, a plain Trainer."""
    L.seed_everything(cfg.seed, workers=True, verbose=False)
    dm, module = _module_and_data(cfg)
    batches = _Batches()
    trainer = L.Trainer(
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[batches],
        **trainer_kwargs,
    )
    trainer.fit(module, datamodule=dm)
    return trainer, module, batches.seen


def test_a_plain_trainer_trains_exactly_as_src_train(train_cfg, tmp_path):
    """The Trainer owns the schedule: handed to a plain `L.Trainer(max_steps=N,
    val_check_interval=V).fit(module, datamodule=dm)`, the module trains on batches that carry
    D's windows and G's, different ones, stops at N with global_step == N, and ends with
    src.train's weights, bit for bit, for the same seed."""
    from src.train import train

    cfg = train_cfg(*TINY_ADV, "checkpoint_every=0")
    torch.set_num_threads(1)
    train(cfg)
    trained = torch.load(tmp_path / "run" / "checkpoints" / "last.ckpt", weights_only=True)

    trainer, module, seen = _plain_fit(cfg, max_steps=4, val_check_interval=2)
    assert trainer.global_step == cfg.iterations == 4
    assert len(seen) == 4
    for d, g in seen:  # two draws of batch_size windows: one for D, one for G
        assert d.shape[0] == g.shape[0] == cfg.data.batch_size
        assert not torch.equal(d, g)
    state = module.state_dict()
    assert trained["state_dict"].keys() == state.keys()
    for key, value in trained["state_dict"].items():
        assert torch.equal(value, state[key]), key
    assert trained["global_step"] == 4


def test_max_steps_counts_iterations(train_cfg):
    """global_step counts iterations, not optimiser steps (two per adversarial iteration), so
    a Trainer's max_steps=N trains N iterations."""
    trainer, module, seen = _plain_fit(train_cfg(*TINY_ADV, "iterations=6"), max_steps=3)
    assert trainer.global_step == len(seen) == 3
