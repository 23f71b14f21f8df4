"""The LightningModule of every architecture and baseline. A training iteration of Li et al.
(protocol §6.6), optimised by hand: the discriminator's objective, eq. (8), on one batch, then
the generator's, eq. (9) = reconstruction (7) + lambda_2 * L2(weights) + lambda_adv *
adversarial term, on the batch's others (`batch["d"]`, the datamodule's). One iteration is one
Trainer step: a plain `L.Trainer(max_steps=N, val_check_interval=V)` trains it as src.train does.
Validation decodes autoregressively (eta = 1): Euler error (protocol §4) and MPJPE."""

from __future__ import annotations

import math
from collections import deque
from pathlib import Path
from typing import Any

import lightning as L
import torch
import torch.nn.functional as F
from lightning.pytorch.utilities import rank_zero_warn
from torch import Tensor, nn

from src.config import instantiate
from src.data.normalization import Normalizer
from src.lit.checkpoints import upgrade
from src.lit.parts import compiled, network, plain
from src.metrics.averages import averages
from src.metrics.euler_error import EulerAngleError, horizon_frame_indices
from src.metrics.kinematics import Skeleton, moving_joints
from src.metrics.mpjpe import MPJPE


class NonFiniteLossError(RuntimeError):
    """Training produced a NaN or inf loss or weight."""


def l2_penalty(module: nn.Module) -> Tensor:
    """TF's l2_regularizer as the reference uses it: sum(w^2) / 2 over weight tensors, biases
    excluded (protocol §6.6). For the logs: its gradient comes from add_l2_gradient_."""
    with torch.no_grad():
        norms = [torch.linalg.vector_norm(p) for p in module.parameters() if p.ndim > 1]
        return torch.stack(norms).square().sum() / 2 if norms else torch.zeros(())


def _host(value: float) -> Tensor:
    """A logged number as a CPU tensor: Lightning copies a float to the device (a host sync)."""
    return torch.tensor(value, dtype=torch.float32)


def add_l2_gradient_(module: nn.Module, weight: float) -> None:
    """Add weight * w, the gradient of weight * l2_penalty(module), to each weight's .grad after
    backward: 3 ms, where backpropagating it took 85 ms of a 1.16 s conv_s2s + adversarial step."""
    for p in module.parameters():
        if p.ndim > 1 and p.grad is not None:
            p.grad.add_(p.detach(), alpha=weight)


class MotionPredictor(L.LightningModule):
    """Built from its config sections (model, sampling, adversarial, metrics, compile) and the
    facts of its data (`parts.data_facts`), which are its hyper-parameters: so
    `MotionPredictor.load_from_checkpoint(path)` rebuilds it without any data file.
    `normalizer`: the datamodule's; else one of the facts' shape, filled by the weights."""

    def __init__(
        self,
        model: dict,
        data: dict,
        sampling: dict | None = None,
        adversarial: dict | None = None,
        metrics: dict | None = None,
        compile: dict | None = None,
        normalizer: Normalizer | None = None,
    ):
        super().__init__()
        model, data, sampling, adversarial = map(plain, (model, data, sampling, adversarial))
        metrics, compile = plain(metrics) or {}, plain(compile) or {}
        self.save_hyperparameters(
            {"model": model, "data": data, "sampling": sampling, "adversarial": adversarial,
             "metrics": metrics, "compile": compile}, logger=False,
        )  # fmt: skip
        self.automatic_optimization = False
        if normalizer is None:  # of the facts' shape and columns; statistics from the weights
            used = torch.zeros(data["num_features"], dtype=torch.bool)
            used[data["used"]] = True
            normalizer = Normalizer(torch.zeros(used.numel()), torch.ones(used.numel()), used)
        self.normalizer = normalizer
        self.net = net = network(model["net"], data, normalizer)
        adv = adversarial if adversarial and adversarial.get("enabled") and self.trainable else {}
        self.discriminator = (
            network(adv["discriminator"], data, normalizer,
                    seq_len=data["observed_len"] + data["future_len"])
            if adv else None
        )  # fmt: skip
        self.lambda_adv, self.lambda_2_d = adv.get("lambda_adv", 0.0), adv.get("lambda_2", 0.0)
        self.reference_fake_slot = adv.get("reference_fake_slot", False)
        if hasattr(net, "objective") and self.adversarial:
            raise ValueError(f"{type(net).__name__} has its own objective: use adversarial=none")
        self.optimizer_factory = instantiate(model["optimizer"]) if self.trainable else None
        self.d_optimizer_factory = instantiate(adv["optimizer"]) if adv else None
        self.lr_decay_every = model.get("lr_decay_every", 10000)
        self.lr_decay_gamma = model.get("lr_decay_gamma", 1.0)
        self.lambda_2, self.grad_clip_norm = model.get("lambda_2", 0.0), model.get("grad_clip_norm")
        self.eta_schedule = instantiate(sampling) if sampling else None
        self.dataset, self.actions = data["dataset"], data["actions"]
        self.frame_ms, self.future_len = data["frame_ms"], data["future_len"]
        # Actions without training files in the data copy trained on: not in average_trained.
        self.untrained_actions = [a for a in self.actions if a in data.get("untrained_actions", [])]
        self.run_info: dict[str, Any] = {}  # commit, config, missing files: in checkpoints
        self.compile_step = compile.get("enabled", False)  # torch.compile the objectives?
        self.compile_mode = compile.get("mode", "reduce-overhead")
        self._compiled: tuple | None = None  # see _objectives
        self._eta_tensor: Tensor | None = None
        self._recent_losses: deque[dict[str, Tensor]] = deque(maxlen=5)

        skeleton = Skeleton.load(self.dataset)
        n, T = len(self.actions), self.future_len
        self.euler = EulerAngleError(n, T, dim_rule=metrics.get("dim_rule", "future"))
        self.mpjpe = MPJPE(skeleton, moving_joints(skeleton, normalizer.used.cpu()), n, T)
        self.horizons = horizon_frame_indices(self.frame_ms, T)
        self.last_results: dict[str, Tensor] = {}
        self.last_averages: dict[str, tuple[list[str], str]] = {}  # averages() of the last one

    @property
    def adversarial(self) -> bool:
        return self.discriminator is not None and self.lambda_adv > 0

    @property
    def trainable(self) -> bool:
        return any(p.requires_grad for p in self.net.parameters())

    def configure_optimizers(self):
        if not self.trainable:
            raise RuntimeError(
                f"{type(self.net).__name__} has no trainable parameters; evaluate it with "
                "`python -m src.eval model=...` instead of training it."
            )
        optimizers = [self.optimizer_factory(params=self.net.parameters())]
        if self.adversarial:
            optimizers.append(self.d_optimizer_factory(params=self.discriminator.parameters()))
        # lr x gamma every `lr_decay_every` iterations (protocol §5, §6.6), stepped by hand.
        schedulers = [
            torch.optim.lr_scheduler.StepLR(o, self.lr_decay_every, self.lr_decay_gamma)
            for o in optimizers
        ]
        return optimizers, schedulers

    def on_train_start(self) -> None:
        self._compiled = None

    def on_fit_start(self) -> None:
        # add_l2_gradient_ adds to the gradients after backward: they must not be scaled.
        if getattr(self.trainer.precision_plugin, "scaler", None) is not None:
            raise ValueError(
                "trainer.precision=16-mixed scales the gradients, which the L2 term of eq. (9) "
                "is added to unscaled; use trainer.precision=32 (default) or bf16-mixed"
            )

    def _sequence(self, observed: Tensor, future: Tensor, fake: Tensor | None = None) -> Tensor:
        """The 75 frames D judges: observed, then `future` (real) or the prediction `fake`, with the
        first future frame in the last observed slot if `reference_fake_slot` (protocol §6.5)."""
        if fake is None:
            return torch.cat([observed, future], dim=1)
        if self.reference_fake_slot:
            observed = torch.cat([observed[:, :-1], future[:, :1]], dim=1)
        return torch.cat([observed, fake], dim=1)

    def _d_objective(
        self, observed: Tensor, future: Tensor, action: Tensor, eta: float | Tensor
    ) -> tuple[Tensor, Tensor]:
        """eq. (8), -log D(real) - log(1 - D(fake)); and the mean logit of the real ones."""
        with torch.no_grad():
            fake = self.net(observed, future.shape[1], action=action, future=future, eta=eta)
        # Real and fake in one call: one weight gradient per layer instead of two summed.
        real_and_fake = torch.cat(
            [self._sequence(observed, future), self._sequence(observed, future, fake)]
        )
        logit_real, logit_fake = self.discriminator(real_and_fake, action.repeat(2)).chunk(2)
        bce, ones, zeros = F.binary_cross_entropy_with_logits, torch.ones_like, torch.zeros_like
        loss = bce(logit_real, ones(logit_real)) + bce(logit_fake, zeros(logit_fake))
        return loss, logit_real.detach().mean()

    def _g_objective(
        self, observed: Tensor, future: Tensor, action: Tensor, eta: float | Tensor
    ) -> tuple[Tensor, Tensor, Tensor]:
        """eq. (9) but its L2 term (a gradient): (loss, reconstruction (7), adversarial or 0)."""
        if hasattr(self.net, "objective"):  # a network's own loss instead of (7): HisRep's L1
            loss_recon = self.net.objective(observed, future)
            return loss_recon, loss_recon.detach(), torch.zeros_like(loss_recon)
        pred = self.net(observed, future.shape[1], action=action, future=future, eta=eta)
        loss_recon = F.mse_loss(pred, future)  # eq. (7), mean over batch x T x D as the reference
        if not self.adversarial:
            return loss_recon, loss_recon.detach(), torch.zeros_like(loss_recon)
        logit = self.discriminator(self._sequence(observed, future, pred), action)
        # eq. (9), non-saturating form -log D(fake) as in the reference (protocol §6.5)
        loss_adv = F.binary_cross_entropy_with_logits(logit, torch.ones_like(logit))
        return loss_recon + self.lambda_adv * loss_adv, loss_recon.detach(), loss_adv.detach()

    def _objectives(self):
        """(compiled?, discriminator objective, generator objective)."""
        if self._compiled is None:
            # auto: on one CUDA device (compiling the inner module of DDP is untested).
            single = self._trainer is None or self.trainer.world_size == 1
            on = compiled(self.compile_step, cuda=self.device.type == "cuda" and single)
            d, g = self._d_objective, self._g_objective
            if on:
                # A fresh compiler state per fit: torch refuses the 9th graph of a function
                # (recompile_limit), and a sweep's earlier fits would count.
                torch.compiler.reset()
                # reduce-overhead captures each objective, forward and backward, in a CUDA graph.
                d = torch.compile(d, mode=self.compile_mode, fullgraph=True)
                g = torch.compile(g, mode=self.compile_mode, fullgraph=True)
            self._compiled = (on, d, g)
        return self._compiled

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        observed, future, action = batch["observed"], batch["future"], batch["action"]
        if self.adversarial and not isinstance(batch.get("d"), dict):
            raise ValueError(
                "with the adversarial regulariser a training batch must carry the "
                "discriminator's own windows under 'd' (observed, future, action), as the "
                "datamodule's with data.discriminator_windows=true; this one has keys "
                f"{sorted(batch)}. Set data.discriminator_windows=true or adversarial=none."
            )
        # In [0, 1]: each schedule checks its own arguments (a network, a float eta).
        eta_in = eta = float(self.eta_schedule(self.global_step)) if self.eta_schedule else 1.0
        compiled, d_objective, g_objective = self._objectives()
        if compiled:
            # One training iteration: outputs of the previous one's CUDA graphs may be reused.
            torch.compiler.cudagraph_mark_step_begin()
            # eta as a tensor refilled in place: a new value neither recompiles nor syncs.
            if self._eta_tensor is None or self._eta_tensor.device != self.device:
                self._eta_tensor = torch.zeros((), device=self.device)
            eta_in = self._eta_tensor.fill_(eta)
        optimizers, schedulers = self.optimizers(), self.lr_schedulers()
        opt_g, opt_d = optimizers if isinstance(optimizers, list) else (optimizers, None)
        logs: dict[str, Tensor] = {"train/eta": _host(eta)}
        d_losses: dict[str, Tensor] = {}

        if self.adversarial:
            # D and G see different windows (protocol §6.6).
            d = batch["d"]
            self.toggle_optimizer(opt_d)
            loss_d_adv, d_real = d_objective(d["observed"], d["future"], d["action"], eta_in)
            loss_d = loss_d_adv.detach() + self.lambda_2_d * l2_penalty(self.discriminator)
            d_losses["loss_d"] = loss_d
            opt_d.zero_grad()
            self.manual_backward(loss_d_adv)
            add_l2_gradient_(self.discriminator, self.lambda_2_d)
            # The torch optimiser: Lightning counts each step of its wrapper in global_step.
            getattr(opt_d, "optimizer", opt_d).step()
            self.untoggle_optimizer(opt_d)
            # Clones: a CUDA graph's outputs are overwritten by its next replay.
            logs |= {"train/loss_d": loss_d.clone(), "train/d_real": d_real.clone()}
            self.toggle_optimizer(opt_g)

        loss_backprop, loss_recon, loss_adv = g_objective(observed, future, action, eta_in)
        loss_recon = loss_recon.clone()
        loss_l2 = l2_penalty(self.net) if self.lambda_2 > 0 else loss_recon.new_zeros(())
        loss_g = loss_backprop.detach() + self.lambda_2 * loss_l2
        # Once per iteration (a host sync), before G's step; nothing is saved after it.
        self._check_finite(d_losses, {"loss_g": loss_g, "loss_recon": loss_recon})
        opt_g.zero_grad()
        self.manual_backward(loss_backprop)
        if self.lambda_2 > 0:
            add_l2_gradient_(self.net, self.lambda_2)
        if self.grad_clip_norm:
            self.clip_gradients(
                opt_g, gradient_clip_val=self.grad_clip_norm, gradient_clip_algorithm="norm"
            )
        opt_g.step()
        if self.adversarial:
            self.untoggle_optimizer(opt_g)
            logs["train/loss_adv"] = loss_adv.clone()
        for sch in schedulers if isinstance(schedulers, list) else [schedulers]:
            sch.step()

        logs |= {"train/loss_g": loss_g, "train/loss_recon": loss_recon, "train/loss_l2": loss_l2}
        logs["train/lr"] = _host(opt_g.param_groups[0]["lr"])
        if self.adversarial:
            logs["train/lr_d"] = _host(opt_d.param_groups[0]["lr"])
        self._recent_losses.append({k: v for k, v in logs.items() if "loss" in k})
        # The bar's number, on the host: Lightning reads it at every batch (a sync on a GPU).
        every = self._trainer.log_every_n_steps if self._trainer is not None else 0
        if every and self.global_step % every == 0:
            self.log("train/loss_recon_bar", _host(loss_recon.item()), prog_bar=True, logger=False)
        self.log_dict(logs, on_step=True, on_epoch=False, batch_size=observed.shape[0])

    def _stop(self, what: str) -> None:
        """Stop, naming the last finite losses and the last good checkpoint (src.train's)."""
        recent = [{k: round(float(v), 6) for k, v in d.items()} for d in self._recent_losses]
        path = getattr(self, "last_checkpoint", None)
        note = f"The last good checkpoint is {path}; resume from it with ckpt_path={path}."
        if path is None or not Path(path).is_file():
            note = "No checkpoint was written before this point."
        raise NonFiniteLossError(
            f"{what}. Last finite losses (oldest first): {recent or 'none yet'}. {note} Lower "
            "the learning rate or check the data."
        )

    def _check_finite(self, *objectives: dict[str, Tensor]) -> None:
        """Stop on a non-finite loss, naming the first objective's (D's makes G's non-finite)."""
        losses = [v.detach() for objective in objectives for v in objective.values()]
        if bool(torch.isfinite(torch.stack(losses)).all()):
            return
        for objective in objectives:
            bad = {k: v.item() for k, v in objective.items() if not torch.isfinite(v)}
            if bad:
                self._stop(f"non-finite loss at training iteration {self.global_step}: {bad}")

    def forward(self, observed: Tensor, future_len: int, action: Tensor | None = None) -> Tensor:
        """Autoregressive prediction in normalised space (eta = 1, no ground truth)."""
        return self.net(observed, future_len, action=action)

    def predict_windows(self, batch: dict[str, Tensor]) -> Tensor:
        """The unnormalised prediction (B, T, F) of test windows (src.scoring swaps in a file's)."""
        pred = self(batch["observed"], batch["future"].shape[1], action=batch["action"])
        return self.normalizer.unnormalize(pred)

    def validation_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        # float32 always: bf16-mixed autocast would move the errors by up to 0.01 rad.
        with torch.autocast(batch["future"].device.type, enabled=False):
            pred_full = self.predict_windows(batch)
            # Ground truth unnormalised as the prediction, as the reference (protocol §4.1).
            gt_full = self.normalizer.unnormalize(batch["future"])
            gt_obs_full = self.normalizer.unnormalize(batch["observed"])
            self.euler.update(pred_full, gt_full, batch["action"], gt_observed_full=gt_obs_full)
            self.mpjpe.update(pred_full, gt_full, batch["action"])

    test_step = validation_step

    def on_validation_epoch_end(self, stage: str = "val") -> None:
        euler, mpjpe = self.euler.compute(), self.mpjpe.compute()
        self.euler.reset(), self.mpjpe.reset()
        self.last_results = {"euler": euler.cpu(), "mpjpe": mpjpe.cpu()}
        present = [i for i in range(len(self.actions)) if not math.isnan(euler[i, 0].item())]
        if self.trainer.sanity_checking or not present:
            return
        self.last_averages = averages([self.actions[i] for i in present], self.untrained_actions)
        index = self.actions.index
        rows = {k: [index(a) for a in names] for k, (names, _) in self.last_averages.items()}
        logs: dict[str, float] = {}
        for name, values in (("euler", euler), ("mpjpe", mpjpe)):
            for ms, k in self.horizons.items():
                # Zero-padded ms so TensorBoard sorts the tags by horizon.
                for i in present:
                    logs[f"{stage}_{name}/{self.actions[i]}/{ms:04d}ms"] = values[i, k].item()
                for average, over in rows.items():  # average (all present), average_trained
                    logs[f"{stage}_{name}/{average}/{ms:04d}ms"] = values[over, k].mean().item()
            idx = list(self.horizons.values())
            logs[f"{stage}/{name}_avg"] = values[present][:, idx].mean().item()
        # compute() all-reduced: sync_dist=True only keeps Lightning from warning once per key.
        self.log_dict(logs, sync_dist=True)

    def on_test_epoch_end(self) -> None:
        self.on_validation_epoch_end("test")

    def _check_finite_weights(self) -> None:
        """A step can make the weights NaN after a finite loss: checked before each validation
        and checkpoint write, so that the previous good last.ckpt is kept."""
        nets = [self.net] if self.discriminator is None else [self.net, self.discriminator]
        bad = [n for net in nets for n, p in net.named_parameters() if not p.isfinite().all()]
        if bad:
            names = ", ".join(bad[:3]) + (", ..." if len(bad) > 3 else "")
            self._stop(
                f"non-finite weights after training iteration {self.global_step} "
                f"({names}); no checkpoint was written from them"
            )

    def on_validation_start(self) -> None:
        self._check_finite_weights()

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        self._check_finite_weights()
        # The run's config, commit and data: what src.eval and src.report read of a model.
        checkpoint["motion"] = {
            **self.run_info,
            "actions": self.actions,
            "untrained_actions": self.untrained_actions,
        }
        # The random state (dropout masks): a resumed run continues as it would have.
        checkpoint["rng"] = {"torch": torch.get_rng_state()}
        if torch.cuda.is_available() and torch.cuda.is_initialized():
            checkpoint["rng"]["cuda"] = torch.cuda.get_rng_state_all()

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        upgrade(checkpoint)  # before Lightning loads the state dict
        if self._trainer is None:  # load_from_checkpoint: for use, not a resume
            self.run_info = checkpoint["motion"]
            return
        # The random state (dropout masks): a resumed run continues as it would have.
        rng = checkpoint.get("rng", {})
        if "torch" in rng:
            torch.set_rng_state(rng["torch"])
        cuda, count = rng.get("cuda"), torch.cuda.device_count()
        if cuda is not None and count:
            if len(cuda) != count:
                rank_zero_warn(
                    f"the checkpoint holds the random state of {len(cuda)} CUDA "
                    f"devices, this machine has {count}: other dropout masks follow"
                )
            for i, state in enumerate(cuda[:count]):
                torch.cuda.set_rng_state(state, i)
