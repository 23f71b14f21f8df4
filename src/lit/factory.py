"""Turns composed Hydra configs into datamodules and LightningModules, and checkpoints back
into them. The entry points (train, eval, visualize) only call these functions."""

from __future__ import annotations

import inspect
import subprocess
from pathlib import Path
from typing import Any

import hydra
import torch
from hydra.errors import InstantiationException
from omegaconf import DictConfig, OmegaConf

from src.data.errors import DataError
from src.data.normalization import Normalizer
from src.lit.predictor import MotionPredictor

PROJECT_ROOT = Path(__file__).resolve().parents[2]


class ConfigError(ValueError):
    """A configuration value or combination that cannot work."""


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable, or does not match the requested config."""


def register_resolvers() -> None:
    if not OmegaConf.has_resolver("project_root"):
        OmegaConf.register_new_resolver("project_root", lambda: str(PROJECT_ROOT))


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
        if isinstance(cause, ValueError):
            target = node.get("_target_", "?") if hasattr(node, "get") else "?"
            raise ConfigError(f"{target}: {cause}") from None
        raise


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
    )


# ---------------------------------------------------------------------------- checkpoints
def read_checkpoint(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(
            f"checkpoint not found: {path}. Runs keep theirs in "
            "outputs/train/runs/<run>/<time>/checkpoints/ (best-*.ckpt, last.ckpt)."
        )
    try:
        # weights_only: a file from elsewhere cannot run code on load; this project's
        # checkpoints hold only tensors and plain containers.
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for a damaged file
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(
            f"cannot read checkpoint {path}: {first[:300]}. The file is damaged (e.g. "
            "truncated by a killed copy) or was not written by torch.save; use another "
            "checkpoint of the run (last.ckpt, best-*.ckpt)."
        ) from err
    if not isinstance(ckpt, dict) or "motion" not in ckpt or "state_dict" not in ckpt:
        raise CheckpointError(
            f"{path} is not a checkpoint written by this project's training (no 'motion' "
            "section). Train one with `python -m src.train ...`."
        )
    return ckpt


def check_compatible(ckpt: dict, cfg: DictConfig, path: str | Path) -> None:
    """Refuse a checkpoint whose model or data differ from what the config asks for."""
    saved = ckpt["motion"]["config"]
    problems = []
    if cfg.get("model") is not None and cfg.model.name != saved["model"]["name"]:
        problems.append(
            f"architecture: checkpoint is {saved['model']['name']}, config asks for "
            f"model={cfg.model.name}"
        )
    if cfg.get("data") is not None and cfg.data.name != saved["data"]["name"]:
        problems.append(
            f"dataset: checkpoint was trained on {saved['data']['name']}, config asks for "
            f"data={cfg.data.name}"
        )
    if cfg.get("model") is not None and not problems:
        want = OmegaConf.to_container(cfg.model.net, resolve=True)
        have = saved["model"]["net"]
        diff = [
            k for k in want if k != "padding" and k in have and want[k] != have[k] and k[0] != "_"
        ]
        if diff:
            problems.append(
                "architecture settings: "
                + ", ".join(f"{k}={have[k]} in checkpoint vs {want[k]}" for k in diff)
            )
    if problems:
        raise CheckpointError(
            f"checkpoint {path} does not match the config: "
            + "; ".join(problems)
            + ". Drop the model=/data= overrides to use the checkpoint's own, or pick the "
            "checkpoint of the run you mean."
        )


def check_normalizer(
    ckpt: dict, normalizer: Normalizer, path: str | Path, actions: list[str] | None = None
) -> None:
    """Resuming training on data whose statistics (or action labels) differ would silently
    change the model."""
    saved_actions = ckpt["motion"].get("actions")
    if actions is not None and saved_actions is not None and list(actions) != saved_actions:
        raise CheckpointError(
            f"actions: checkpoint {path} was trained on actions {saved_actions}, the data "
            f"config gives {list(actions)}. Set data.actions as in the run that wrote it."
        )
    state = ckpt["state_dict"]
    used = state.get("normalizer.used")
    if used is None:
        return
    if used.shape != normalizer.used.shape or int(used.sum()) != normalizer.pose_dim:
        raise CheckpointError(
            f"pose dimension: checkpoint {path} uses {int(used.sum())} of {used.numel()} "
            f"columns, the data gives {normalizer.pose_dim} of {normalizer.num_features}. "
            "It was trained on another dataset or action set."
        )
    if not (
        torch.equal(used, normalizer.used.cpu())
        and torch.allclose(state["normalizer.mean"], normalizer.mean.cpu(), atol=1e-5)
        and torch.allclose(state["normalizer.std"], normalizer.std.cpu(), atol=1e-5)
    ):
        raise CheckpointError(
            f"normalisation statistics: checkpoint {path} was trained with different "
            "statistics (different training files or actions). Use the same data config "
            "(data.actions, subjects, allow_partial) as the run that wrote it."
        )


def module_from_checkpoint(ckpt: dict, cfg: DictConfig, path: str | Path):
    """Rebuild (datamodule, module) from a checkpoint; the normaliser comes from the checkpoint,
    so evaluation never re-reads the training data."""
    saved = OmegaConf.create(ckpt["motion"]["config"])
    check_compatible(ckpt, cfg, path)
    data_cfg = saved.data
    # Where data lives is a property of this machine, not of the checkpoint.
    for key in ("data_dir", "archive_dir"):
        data_cfg[key] = cfg.paths[key]
    if cfg.get("data") is not None:  # evaluation settings (protocol, batch size) may differ
        for key in ("eval_protocol", "eval_windows_per_action", "eval_stride", "allow_partial"):
            data_cfg[key] = cfg.data[key]
    if cfg.get("protocol"):
        data_cfg.eval_protocol = cfg.protocol
    state = ckpt["state_dict"]
    normalizer = Normalizer.empty(state["normalizer.mean"].numel())
    normalizer.load_state_dict(
        {k.removeprefix("normalizer."): v for k, v in state.items() if k.startswith("normalizer.")}
    )
    dm = build_datamodule(data_cfg, normalizer=normalizer)
    dm.prepare_data()
    dm.setup("validate")
    module_cfg = OmegaConf.merge(saved, {"metrics": cfg.metrics, "sampling": saved.get("sampling")})
    module = build_module(module_cfg, dm, run_info=ckpt["motion"])
    missing, unexpected = module.load_state_dict(state, strict=False)
    missing = [k for k in missing if not k.startswith(("euler.", "mpjpe."))]
    if missing or unexpected:
        raise CheckpointError(
            f"checkpoint {path} does not fit the rebuilt model: missing {missing[:5]}, "
            f"unexpected {unexpected[:5]}. It was written by an incompatible version."
        )
    return dm, module
