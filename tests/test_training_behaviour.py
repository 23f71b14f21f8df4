"""What one training iteration does, checked on what the optimisers step with (issue #27).

Each test watches the optimisers from outside, through PyTorch's step hooks: the gradients and
the learning rate every `optimizer.step()` sees, and the eta the network is run with. They
fail when the method is wrong, whatever the code that computes it looks like:

- without the regulariser the generator steps with the gradient of eq. (7);
- the discriminator (eq. 8) and the generator (eq. 9) learn from different windows (protocol
  6.6);
- the generator's adversarial term pushes D(fake) towards "real" (eq. 9, non-saturating);
- Martinez's gradient clipping at global norm 5 (protocol 5) is applied;
- the learning rate of both optimisers decays on schedule (protocol 5, 6.6);
- a resumed run continues the eta schedule of eq. (10) at its checkpoint's iteration.

Tiny networks on the synthetic data: a few seconds each.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import lightning as L
import pytest
import torch

from src.build import build_datamodule, build_module
from src.prepare import compose_config
from tests.objects import TINY_CONV, fit_batches

TINY_G = ["model=conv_s2s", "model.net.nf=2", "model.net.d_z=8", "data.batch_size=4"]
TINY_GRU = ["model=gru_s2s", "model.net.hidden=16", "data.batch_size=4"]
G_NO_DROPOUT = ["model.net.dropout=[0,0,0]", "model.net.decoder_dropout=0"]
NO_DROPOUT = [*G_NO_DROPOUT, "+adversarial.discriminator.dropout=[0,0,0]"]


@dataclass
class Step:
    """One optimiser step as the optimiser saw it, just before it changed the weights."""

    net: str  # "g" (the generator's optimiser) or "d" (the discriminator's)
    lr: float
    grads: dict[str, torch.Tensor]  # parameter name -> the gradient stepped with
    weights: dict[str, torch.Tensor]  # every weight of the module at that moment


class StepRecorder(L.Callback):
    """Records every optimiser step of a fit, in order (see Step)."""

    def __init__(self):
        self.steps: list[Step] = []

    def on_train_start(self, trainer, pl_module):
        owner = {id(p): ("g", n) for n, p in pl_module.net.named_parameters()}
        if pl_module.discriminator is not None:
            owner |= {id(p): ("d", n) for n, p in pl_module.discriminator.named_parameters()}
        for opt in trainer.optimizers:
            opt.register_step_pre_hook(partial(self._record, owner, pl_module))

    def _record(self, owner, module, opt, args, kwargs):
        params = [p for group in opt.param_groups for p in group["params"]]
        (net,) = {owner[id(p)][0] for p in params}  # one optimiser per network
        grads = {owner[id(p)][1]: p.grad.clone() for p in params if p.grad is not None}
        weights = {k: v.detach().clone() for k, v in module.state_dict().items()}
        self.steps.append(Step(net, opt.param_groups[0]["lr"], grads, weights))

    def of(self, net: str) -> list[Step]:
        return [s for s in self.steps if s.net == net]


def _fit(module, batches: list[dict[str, torch.Tensor]], seed: int = 0) -> StepRecorder:
    """Train `module` one iteration per batch (CPU, no validation); the steps it took."""
    recorder = StepRecorder()
    fit_batches(module, batches, [recorder], seed)
    return recorder


@pytest.fixture
def setup(tmp_path, synthetic_data_dir):
    """setup(*overrides) -> (datamodule, a factory of fresh identical modules)."""

    def make(*overrides: str):
        cfg = compose_config(
            "train",
            ["data=synthetic", "trainer=cpu", "iterations=4", "val_every=2", *overrides],
            tmp_path / "run",
            synthetic_data_dir,
        )
        dm = build_datamodule(cfg.data)
        dm.prepare_data()
        dm.setup("fit")

        def module():
            L.seed_everything(0, verbose=False)
            return build_module(cfg, dm)

        return dm, module

    return make


def _batch(dm, index: int = 0) -> dict[str, torch.Tensor]:
    """The index-th training batch the datamodule draws (both draws of an adversarial step)."""
    for i, batch in enumerate(dm.train_dataloader()):
        if i == index:
            return batch
    raise AssertionError(f"fewer than {index + 1} training batches")


def _part_replaced(batch, other, part: str) -> dict:
    """`batch` with the discriminator's windows (part "d") or the generator's ("g") taken from
    `other`."""
    if part == "d":
        return {**batch, "d": other["d"]}
    return {**{k: v for k, v in other.items() if k != "d"}, "d": batch["d"]}


def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    assert a.keys() == b.keys()
    return all(torch.equal(a[k], b[k]) for k in a)


def _flat(tensors) -> torch.Tensor:
    return torch.cat([t.flatten() for t in tensors])


# ------------------------------------------------------------------ eq. (7), (8), (9), protocol 6.6
def test_without_regulariser_the_generator_steps_with_the_reconstruction_gradient(setup):
    """eq. (7): the reconstruction loss is the mean squared error over batch x frames x
    dimensions in normalised space (protocol 6.6); with no adversarial term and no L2 it is
    all the generator steps with (dropout off and eta = 1, so the prediction is repeatable)."""
    dm, module = setup(
        *TINY_G, *G_NO_DROPOUT, "adversarial=none", "sampling=full", "model.lambda_2=0"
    )
    m = module()
    batch = _batch(dm, 0)
    (g,) = _fit(m, [batch]).of("g")
    m.load_state_dict(g.weights)
    params = dict(m.net.named_parameters())
    future = batch["future"]
    prediction = m.net(batch["observed"], future.shape[1], action=batch["action"])
    expected = torch.autograd.grad((prediction - future).square().mean(), list(params.values()))
    for name, want in zip(params, expected, strict=True):
        torch.testing.assert_close(g.grads[name], want, msg=name)


def test_discriminator_and_generator_learn_from_different_windows(setup):
    """Protocol 6.6: each iteration is one D step on a batch, then one G step on a *different*
    batch. Changing one half of the step's windows must change the gradient of exactly one of
    the two optimisers, and the other half the other one's. The discriminator's learning rate
    is 0 so that the G step cannot depend on the D half through D's weights."""
    dm, module = setup(*TINY_CONV, "adversarial.optimizer.lr=0")
    batch, other = _batch(dm, 0), _batch(dm, 1)
    assert batch["d"]["observed"].shape == batch["observed"].shape  # two draws per step
    assert not torch.equal(batch["observed"], other["observed"])

    def step_gradients(b):
        steps = _fit(module(), [b])
        (g,), (d,) = steps.of("g"), steps.of("d")
        return g.grads, d.grads

    g, d = step_gradients(batch)
    g_dependence, d_dependence = [], []
    for part in ("d", "g"):
        g_part, d_part = step_gradients(_part_replaced(batch, other, part))
        g_dependence.append(not _same(g, g_part))
        d_dependence.append(not _same(d, d_part))
    # Each objective sees its own windows only.
    assert g_dependence == [False, True], f"G depends on the windows of (d, g): {g_dependence}"
    assert d_dependence == [True, False], f"D depends on the windows of (d, g): {d_dependence}"


def test_the_generator_steps_towards_fooling_the_discriminator(setup):
    """eq. (9): the adversarial term is -log D(fake) (the reference's non-saturating form),
    so the generator's step raises the discriminator's logit on the generator's predictions.
    With lambda_adv large the step is that term; its gradient must point against the gradient
    of D's mean logit on the predicted sequences (observed frames, then the prediction)."""
    dm, module = setup(
        *TINY_CONV, *NO_DROPOUT, "sampling=full", "adversarial.lambda_adv=100", "model.lambda_2=0"
    )
    m = module()
    first = {k: v for k, v in _batch(dm, 0).items() if k != "d"}
    # D's windows the same as G's: the G step judges these predictions whatever it takes.
    both = {**first, "d": first}
    (g,) = _fit(m, [both]).of("g")

    # D's logit on the predictions, as a function of the generator's weights at the G step.
    m.load_state_dict(g.weights)
    m.eval()
    observed, action = first["observed"], first["action"]
    params = dict(m.net.named_parameters())
    prediction = m.net(observed, first["future"].shape[1], action=action)
    logit = m.discriminator(torch.cat([observed, prediction], dim=1), action).mean()
    towards_real = torch.autograd.grad(logit, list(params.values()))
    stepped = _flat(g.grads[k] for k in params)
    cosine = torch.nn.functional.cosine_similarity(stepped, _flat(towards_real), dim=0)
    # Gradient descent moves against `stepped`: along +grad(logit), towards "real".
    assert cosine < -0.9, f"the generator's step does not raise D(fake): cosine {cosine:.3f}"


# ------------------------------------------------------------------ protocol 5: clipping
@pytest.mark.parametrize("adversarial", ["none", "li2018"])
def test_gru_steps_with_the_gradient_clipped_to_norm_5(setup, adversarial):
    """Martinez et al. clip the generator's gradient to global norm 5 (protocol 5): the step
    takes the unclipped gradient scaled to norm 5, with or without the regulariser."""
    dm, module = setup(*TINY_GRU, f"adversarial={adversarial}")  # gru_s2s clips at 5
    batch = _batch(dm, 0)
    (clipped,) = _fit(module(), [batch]).of("g")
    _, unclipped = setup(*TINY_GRU, f"adversarial={adversarial}", "model.grad_clip_norm=null")
    (raw,) = _fit(unclipped(), [batch]).of("g")

    raw_norm = torch.linalg.vector_norm(_flat(raw.grads.values()))
    assert raw_norm > 5.0, "the check needs a gradient above the clip norm"
    stepped_norm = torch.linalg.vector_norm(_flat(clipped.grads.values()))
    assert stepped_norm == pytest.approx(5.0, rel=1e-4)
    for k in raw.grads:  # the same direction: only scaled
        torch.testing.assert_close(clipped.grads[k], raw.grads[k] * (5.0 / raw_norm), msg=k)


# ------------------------------------------------------------------ protocol 5, 6.6: lr decay
def test_both_optimisers_decay_their_learning_rate_on_schedule(setup):
    """lr x gamma every `lr_decay_every` iterations, for the generator's and the
    discriminator's optimiser alike (protocol 6.6: both Adam at 5e-5, x0.99 every 10,000):
    here each starts at its own rate and halves every 2 iterations."""
    dm, module = setup(
        *TINY_CONV,
        "model.optimizer.lr=1e-3",
        "adversarial.optimizer.lr=4e-3",
        "model.lr_decay_every=2",
        "model.lr_decay_gamma=0.5",
        "iterations=6",  # the module stops a fit there; 5 batches here
    )
    steps = _fit(module(), [_batch(dm)] * 5)
    factors = [1, 1, 0.5, 0.5, 0.25]
    assert [s.lr for s in steps.of("g")] == pytest.approx([1e-3 * f for f in factors])
    assert [s.lr for s in steps.of("d")] == pytest.approx([4e-3 * f for f in factors])
    # Each iteration: the D step, then the G step.
    assert [s.net for s in steps.steps] == ["d", "g"] * 5


# ------------------------------------------------------------------ eq. (10) across a resume
def test_a_resumed_run_continues_the_eta_schedule(tmp_path, synthetic_data_dir, monkeypatch):
    """eta of eq. (10) is a function of the iteration: a run resumed from its checkpoint at
    iteration 2 of a linear ramp 0 -> 1 over 4 iterations trains its next steps with eta
    0.5 and 0.75, as the uninterrupted run does, not with the ramp's start again."""
    from src.models.gru_s2s import GRUSeq2Seq
    from src.train import train

    used: list[float] = []
    forward = GRUSeq2Seq.forward

    def recording_forward(self, *args, **kwargs):
        if self.training:  # training steps only, not validation
            used.append(float(kwargs.get("eta", 1.0)))
        return forward(self, *args, **kwargs)

    monkeypatch.setattr(GRUSeq2Seq, "forward", recording_forward)

    def run(folder: str, *overrides: str):
        args = [
            "data=synthetic",
            "trainer=cpu",
            "trainer.enable_progress_bar=false",
            *TINY_GRU,
            "sampling=linear",
            "sampling.steps=4",
            "val_every=2",
            "checkpoint_every=0",
            "media_every=0",
            *overrides,
        ]
        train(compose_config("train", args, tmp_path / folder, synthetic_data_dir))
        return tmp_path / folder / "checkpoints" / "last.ckpt"

    checkpoint = run("first", "iterations=2")
    assert used == pytest.approx([0.0, 0.25])
    used.clear()
    run("resumed", "iterations=4", f"ckpt_path={checkpoint}")
    assert used == pytest.approx([0.5, 0.75]), f"the resumed steps used eta {used}"
