"""The one place where the tests of the model's wiring, config keys, boundaries and frame paths
(tests/test_wiring.py, test_config_keys.py, test_boundaries.py, test_frame_paths.py) turn a
config into the objects a run trains and evaluates with. They use the entry points' public
functions only; when src.build's API changes, this file is the one to edit.

What a training iteration does is watched from outside, as tests/test_training_behaviour.py
does: PyTorch's optimiser step hooks record what each optimiser steps with (its class, its
settings, the gradients, the weights), and a forward hook the eta the network is run with.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import lightning as L
import torch
from omegaconf import DictConfig

from src.build import build_datamodule, build_module, build_parts
from src.config import (
    ConfigError,  # noqa: F401  (what a refused config raises)
    check,
)
from src.data.errors import DataError  # noqa: F401  (what objects.validate may raise)
from src.prepare import compose_config
from src.results import build_for_evaluation


# ------------------------------------------------------------------------------ threads
def one_thread():
    """A generator fixture body: torch on one thread while a module's tests run, then as it
    was. Their networks are tiny, and a pool's hand-offs cost more than the arithmetic: the
    tests of issue 41 took 4x longer on two threads of a busy 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# ------------------------------------------------------------------------------ configs
# The smallest conv seq2seq with its adversarial regulariser (model=conv_s2s defaults to it):
# a few hundred weights, so a test trains it in seconds.
TINY_CONV = ["model=conv_s2s", "model.net.nf=2", "model.net.d_z=8", "data.batch_size=4",
             "adversarial=li2018", "adversarial.discriminator.nf=2",
             "adversarial.discriminator.d_z=8", "adversarial.discriminator.d_fc=4"]  # fmt: skip
QUIET = ["trainer=cpu", "trainer.enable_progress_bar=false", "media_every=0"]


def compose(overrides: list[str], out_dir: Path, data_dir: Path, name: str = "train") -> DictConfig:
    """The config `python -m src.<name> overrides...` runs with (run folder `out_dir`)."""
    return compose_config(name, list(overrides), out_dir, data_dir)


def validate(cfg: DictConfig) -> None:
    """The checks `src.train` runs on a config before anything else (ConfigError, or the
    DataError of the data module's own check, if refused): the declared types and ranges, the
    cross-field checks, then the constructors that check their own arguments."""
    check(cfg, "train")
    build_parts(cfg)


# ------------------------------------------------------------------------------ objects
def datamodule(data_cfg: DictConfig, stage: str | None = "fit"):
    """The datamodule of a data config, set up for `stage` (None: constructed only, its
    arguments checked, no file read)."""
    dm = build_datamodule(data_cfg)
    if stage is not None:
        dm.prepare_data()
        dm.setup(stage)
    return dm


def module(cfg: DictConfig, dm, seed: int = 0):
    """The LightningModule `src.train` builds for `cfg` on `dm`, its weights drawn from `seed`."""
    L.seed_everything(seed, verbose=False)
    return build_module(cfg, dm)


def networks(built) -> tuple[torch.nn.Module, torch.nn.Module | None]:
    """(generator, discriminator or None) of a built module."""
    return built.net, built.discriminator


def optimisers(built) -> tuple[list[torch.optim.Optimizer], list]:
    """The optimisers (generator's first) and learning-rate schedulers a built module trains
    with, as Lightning's configure_optimizers hands them to the Trainer."""
    out = built.configure_optimizers()
    if isinstance(out, torch.optim.Optimizer):
        return [out], []
    if isinstance(out, dict):
        out = [out]
    if isinstance(out, (list, tuple)) and out and isinstance(out[0], dict):
        opts = [d["optimizer"] for d in out]
        scheds = [d["lr_scheduler"] for d in out if d.get("lr_scheduler") is not None]
        scheds = [s["scheduler"] if isinstance(s, dict) else s for s in scheds]
        return opts, scheds
    opts, scheds = out
    opts = list(opts) if isinstance(opts, (list, tuple)) else [opts]
    scheds = [s["scheduler"] if isinstance(s, dict) else s for s in scheds]
    return opts, list(scheds)


def evaluation_objects(cfg: DictConfig):
    """(datamodule of the test windows, module) as src.eval and src.visualize build them."""
    return build_for_evaluation(cfg)


def train_run(cfg: DictConfig) -> Path:
    """Run `python -m src.train` in-process on `cfg`; its run folder."""
    from src.train import train

    train(cfg)
    return Path(cfg.paths.output_dir)


# ------------------------------------------------------------------------------ training
@dataclass
class Step:
    """One optimiser step, as the optimiser saw it just before it changed the weights."""

    net: str  # "g": the generator's optimiser, "d": the discriminator's
    kind: str  # the optimiser's class name
    settings: dict[str, Any]  # its param group's settings: lr, betas, eps, weight_decay, ...
    grads: dict[str, torch.Tensor]  # parameter name -> the gradient it steps with
    weights: dict[str, torch.Tensor]  # parameter name -> the value it steps from


@dataclass
class Trace:
    steps: list[Step] = field(default_factory=list)
    etas: list[float] = field(default_factory=list)  # eta of every training forward

    def of(self, net: str) -> list[Step]:
        return [s for s in self.steps if s.net == net]


class _Recorder(L.Callback):
    def __init__(self, trace: Trace):
        self.trace = trace

    def on_train_start(self, trainer, pl_module):
        g, d = networks(pl_module)
        owner = {id(p): ("g", n) for n, p in g.named_parameters()}
        if d is not None:
            owner |= {id(p): ("d", n) for n, p in d.named_parameters()}
        for opt in trainer.optimizers:
            opt.register_step_pre_hook(partial(self._step, owner))
        g.register_forward_pre_hook(self._forward, with_kwargs=True)

    def _step(self, owner, opt, args, kwargs):
        params = [p for group in opt.param_groups for p in group["params"]]
        (net,) = {owner[id(p)][0] for p in params}  # one optimiser per network
        settings = {k: v for k, v in opt.param_groups[0].items() if k != "params"}
        grads = {owner[id(p)][1]: p.grad.clone() for p in params if p.grad is not None}
        weights = {owner[id(p)][1]: p.detach().clone() for p in params}
        self.trace.steps.append(Step(net, type(opt).__name__, settings, grads, weights))

    def _forward(self, net, args, kwargs):
        if net.training:
            eta = kwargs.get("eta", args[4] if len(args) > 4 else 1.0)
            self.trace.etas.append(float(eta))


def with_d_windows(batch: dict[str, torch.Tensor]) -> dict:
    """A flat batch of 2n windows as an adversarial iteration's: the first n the
    discriminator's (under "d"), the other n the generator's."""
    d, g = {}, {}
    for k, v in batch.items():
        d[k], g[k] = v.chunk(2)
    return {**g, "d": d}


def train_steps(built, batches: list[dict[str, torch.Tensor]], seed: int = 0) -> Trace:
    """Train `built` one iteration per batch (CPU, no validation); what it stepped with. With
    the regulariser a flat batch is split by `with_d_windows`."""
    if built.adversarial:
        batches = [b if "d" in b else with_d_windows(b) for b in batches]
    trace = Trace()
    built.train()  # as built: a probe of it may have left it in eval mode
    fit_batches(built, batches, [_Recorder(trace)], seed)
    return trace


def fit_batches(module, batches: list[dict], callbacks=(), seed: int = 0) -> None:
    """A plain Trainer fits `module` one iteration per batch (CPU, no validation, no files)."""
    trainer = L.Trainer(
        accelerator="cpu",
        max_epochs=1,
        limit_val_batches=0,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=list(callbacks),
    )
    torch.manual_seed(seed)  # the same dropout masks in every fit of a test
    trainer.fit(module, train_dataloaders=torch.utils.data.DataLoader(batches, batch_size=None))


# ------------------------------------------------------------------------------ frame paths
def export_windows(cfg: DictConfig) -> Path:
    """Run `python -m src.export_windows` in-process on `cfg`; the .npz it wrote."""
    from src.export_windows import export

    return export(cfg)


def visualised_positions(dm, built, index: int) -> tuple[dict[str, Any], Callable]:
    """The joint positions src.visualize draws for evaluation window `index` (every observed
    frame shown), by row name, and the function that turns raw frames into such positions."""
    import importlib

    from src import visualize

    rows, _, _ = visualize.window_rows(dm, built, index, True, dm.observed_len)
    positions = importlib.import_module(visualize.window_rows.__module__).positions
    return {row.label: row.positions for row in rows}, positions


def forecaster(checkpoint: Path):
    """The MotionForecaster of a checkpoint, as a user loads it."""
    from src.inference import MotionForecaster

    return MotionForecaster.from_checkpoint(checkpoint)
