"""Turns composed Hydra configs into datamodules and LightningModules. The entry points
(train, eval, visualize) only call these functions; checkpoints live in src/lit/checkpoints.py."""

from __future__ import annotations

import inspect
import subprocess
from pathlib import Path
from typing import Any

import hydra
from hydra.errors import InstantiationException
from lightning.fabric.utilities.exceptions import MisconfigurationException
from omegaconf import DictConfig, OmegaConf

from src.data.errors import DataError
from src.data.normalization import Normalizer
from src.lit.predictor import MotionPredictor

PROJECT_ROOT = Path(__file__).resolve().parents[2]


class ConfigError(ValueError):
    """A configuration value or combination that cannot work."""


def register_resolvers() -> None:
    if not OmegaConf.has_resolver("project_root"):
        OmegaConf.register_new_resolver("project_root", lambda: str(PROJECT_ROOT))
    if not OmegaConf.has_resolver("evaluated"):
        from src.lit.runs import evaluated_name  # here: runs.py imports this module

        OmegaConf.register_new_resolver("evaluated", evaluated_name)


def git_commit() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=PROJECT_ROOT,
            capture_output=True,
            text=True,
            check=True,
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=PROJECT_ROOT,
            capture_output=True,
            text=True,
        ).stdout.strip()
        return out.stdout.strip() + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _instantiate(node, **kwargs):
    """hydra.utils.instantiate, but a bad value reaches the user as the project's own one-line
    error: Hydra wraps whatever the constructor raised in an InstantiationException, which the
    CLI would print as a traceback."""
    try:
        return hydra.utils.instantiate(node, **kwargs)
    except InstantiationException as err:
        cause = err.__cause__
        if isinstance(cause, (DataError, ConfigError)):
            raise cause from None
        if isinstance(cause, (ValueError, MisconfigurationException)):
            target = node.get("_target_", "?") if hasattr(node, "get") else "?"
            raise ConfigError(f"{target}: {cause}") from None
        raise


def build_trainer(trainer_cfg: DictConfig, **kwargs):
    """The Lightning Trainer of `trainer_cfg` (kwargs: what only the entry point knows); a
    setting Lightning refuses (devices=0, an unknown strategy) is a one-line ConfigError."""
    return _instantiate(trainer_cfg, **kwargs)


# ---------------------------------------------------------------------------- data
def build_datamodule(data_cfg: DictConfig, normalizer: Normalizer | None = None):
    kwargs = {k: v for k, v in data_cfg.items() if k != "name"}
    dm = _instantiate(kwargs, _convert_="all")
    if normalizer is not None:
        dm.set_normalizer(normalizer)
    return dm


# ---------------------------------------------------------------------------- models
def _instantiate_with_data(node: DictConfig, dm, **extra):
    """Instantiate a network config, filling in what only the data knows (pose dimension,
    number of actions, the convolution padding of protocol §6.7, the normaliser)."""
    target = hydra.utils.get_class(node._target_)
    accepted = inspect.signature(target).parameters
    kwargs: dict[str, Any] = {"pose_dim": dm.pose_dim, "num_actions": dm.num_actions}
    if "normalizer" in accepted:
        kwargs["normalizer"] = dm.normalizer
    if node.get("padding") == "auto":
        kwargs["padding"] = dm.conv_padding
    kwargs.update(extra)
    return _instantiate(node, **kwargs, _convert_="all")


def build_module(cfg: DictConfig, dm, run_info: dict | None = None) -> MotionPredictor:
    """The LightningModule for `cfg.model` (+ `cfg.adversarial`, `cfg.sampling`) on `dm`."""
    net = _instantiate_with_data(cfg.model.net, dm)
    adv = cfg.get("adversarial") or {"enabled": False}
    discriminator = d_optimizer = None
    trainable = any(p.requires_grad for p in net.parameters())
    if adv.get("enabled") and trainable:
        discriminator = _instantiate_with_data(
            adv.discriminator, dm, seq_len=dm.observed_len + dm.future_len
        )
        d_optimizer = hydra.utils.instantiate(adv.optimizer)
    return MotionPredictor(
        net=net,
        normalizer=dm.normalizer,
        dataset=dm.dataset_name,
        actions=dm.actions,
        frame_ms=dm.frame_ms,
        future_len=dm.future_len,
        optimizer=hydra.utils.instantiate(cfg.model.optimizer) if trainable else None,
        lr_decay_every=cfg.model.get("lr_decay_every", 10000),
        lr_decay_gamma=cfg.model.get("lr_decay_gamma", 1.0),
        lambda_2=cfg.model.get("lambda_2", 0.0),
        grad_clip_norm=cfg.model.get("grad_clip_norm"),
        eta_schedule=_instantiate(cfg.sampling) if cfg.get("sampling") else None,
        discriminator=discriminator,
        d_optimizer=d_optimizer,
        lambda_adv=adv.get("lambda_adv", 0.0) if discriminator is not None else 0.0,
        lambda_2_d=adv.get("lambda_2", 0.0),
        reference_fake_slot=adv.get("reference_fake_slot", False),
        dim_rule=cfg.metrics.dim_rule,
        run_info=run_info,
        compile=cfg.get("compile", {}).get("enabled", "auto"),
        compile_mode=cfg.get("compile", {}).get("mode", "reduce-overhead"),
    )
