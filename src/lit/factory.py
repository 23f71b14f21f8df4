"""Composed Hydra configs, and checkpoints, into datamodules and LightningModules: the entry
points and MotionForecaster build through these functions alone."""

from __future__ import annotations

import inspect
import subprocess
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import hydra
import torch
from hydra.errors import InstantiationException
from lightning.fabric.utilities.exceptions import MisconfigurationException
from omegaconf import DictConfig, OmegaConf

from src.data.errors import DataError
from src.data.normalization import Normalizer
from src.lit.checkpoints import CheckpointError, check_compatible, read_checkpoint
from src.lit.config import ConfigError
from src.lit.predictor import MotionPredictor

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def git_commit() -> str:
    """The short commit hash, "-dirty" with uncommitted changes to tracked files."""
    cmd = ["git", "describe", "--always", "--dirty", "--exclude=*"]  # no tag names
    try:
        run = subprocess.run(cmd, cwd=PROJECT_ROOT, capture_output=True, text=True, check=True)
        return run.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _instantiate(node, **kwargs):
    """hydra.utils.instantiate; a constructor's refusal is one line, not Hydra's traceback."""
    try:
        return hydra.utils.instantiate(node, **kwargs)
    except InstantiationException as err:
        cause = err.__cause__
        if isinstance(cause, (DataError, ConfigError)):
            raise cause from None
        if isinstance(cause, (ValueError, MisconfigurationException)):
            raise ConfigError(f"{node.get('_target_', '?')}: {cause}") from None
        raise


# The Trainer of a trainer config (+ kwargs); a setting Lightning refuses is a ConfigError.
build_trainer = _instantiate


def build_parts(cfg: DictConfig) -> None:
    """Build, and drop, the data module, eta schedule and optimisers (on a stand-in parameter):
    their constructors' refusals come before the run folder is made and any data is read."""
    build_datamodule(cfg.data)
    if cfg.get("sampling"):
        _instantiate(cfg.sampling)
    for key in ("model.optimizer", "adversarial.optimizer"):  # lr > 0 is checked for both
        node = OmegaConf.select(cfg, key)
        if node is not None:
            try:
                _instantiate(node)([torch.nn.Parameter(torch.zeros(1))])
            except ValueError as err:  # torch.optim's refusal of an argument
                raise ConfigError(f"{key}: {err}") from None


def build_datamodule(data_cfg: DictConfig, normalizer: Normalizer | None = None):
    kwargs = {k: v for k, v in data_cfg.items() if k != "name"}
    dm = _instantiate(kwargs, _convert_="all")
    if normalizer is not None:
        dm.set_normalizer(normalizer)
    return dm


def _instantiate_with_data(node: DictConfig, dm, **extra):
    """A network, with what only the data knows (padding: protocol §6.7)."""
    kwargs: dict[str, Any] = {"pose_dim": dm.pose_dim, "num_actions": dm.num_actions, **extra}
    if "normalizer" in inspect.signature(hydra.utils.get_class(node._target_)).parameters:
        kwargs["normalizer"] = dm.normalizer
    if node.get("padding") == "auto":
        kwargs["padding"] = dm.conv_padding
    return _instantiate(node, **kwargs, _convert_="all")


def build_module(cfg: DictConfig, dm, run_info: dict | None = None) -> MotionPredictor:
    """The LightningModule of `cfg` on `dm`, a set-up datamodule or load_trained's stand-in."""
    net = _instantiate_with_data(cfg.model.net, dm)
    trainable = any(p.requires_grad for p in net.parameters())
    model, adv, compile_ = cfg.model, cfg.get("adversarial") or {}, cfg.get("compile") or {}
    settings = ("lr_decay_every", "lr_decay_gamma", "lambda_2", "grad_clip_norm")
    kwargs = {k: model[k] for k in settings if k in model}
    if adv.get("enabled") and trainable:
        kwargs |= {
            "discriminator": _instantiate_with_data(
                adv.discriminator, dm, seq_len=dm.observed_len + dm.future_len
            ),
            "d_optimizer": hydra.utils.instantiate(adv.optimizer),
            "lambda_adv": adv.get("lambda_adv", 0.0),
            "lambda_2_d": adv.get("lambda_2", 0.0),
            "reference_fake_slot": adv.get("reference_fake_slot", False),
        }
    return MotionPredictor(
        net,
        dm.normalizer,
        dataset=dm.dataset_name,
        actions=dm.actions,
        frame_ms=dm.frame_ms,
        future_len=dm.future_len,
        optimizer=hydra.utils.instantiate(model.optimizer) if trainable else None,
        eta_schedule=_instantiate(cfg.sampling) if cfg.get("sampling") else None,
        dim_rule=cfg.metrics.dim_rule,
        run_info=run_info,
        compile=compile_.get("enabled", False),
        compile_mode=compile_.get("mode", "reduce-overhead"),
        untrained_actions=dm.untrained_actions,
        **kwargs,
    )


def load_trained(path: str | Path, cfg: DictConfig | None = None) -> MotionPredictor:
    """The one way to load a trained model, from the checkpoint alone (no data file is read): its
    MotionPredictor in eval mode, saved config in `.run_info["config"]`. `cfg`, an evaluation
    config: refuse a checkpoint of another model= / data=; take its `metrics.dim_rule`."""
    ckpt = read_checkpoint(path)
    if cfg is not None:
        check_compatible(ckpt, cfg, path)
    motion, state = ckpt["motion"], ckpt["state_dict"]
    saved = OmegaConf.create(motion["config"])
    if "normalizer.mean" not in state:
        raise CheckpointError(f"{path} holds no normaliser (normalizer.* buffers)")
    normalizer = Normalizer.empty(state["normalizer.mean"].numel())
    normalizer.load_state_dict(
        {k.removeprefix("normalizer."): v for k, v in state.items() if k.startswith("normalizer.")}
    )
    # What build_module reads of a set-up datamodule: its class's attributes, the saved lengths.
    data, actions = hydra.utils.get_class(saved.data._target_), list(motion["actions"])
    facts = SimpleNamespace(
        normalizer=normalizer,
        pose_dim=normalizer.pose_dim,
        actions=actions,
        num_actions=len(actions),
        # Of the data copy it was trained on (older checkpoints lack it: none known).
        untrained_actions=motion.get("untrained_actions", []),
        **{k: getattr(data, k) for k in ("dataset_name", "conv_padding", "frame_ms")},
        **{k: saved.data[k] for k in ("observed_len", "future_len")},
    )
    if cfg is not None and cfg.get("metrics") is not None:
        saved.metrics = cfg.metrics
    try:
        module = build_module(saved, facts, run_info=motion)
    except (InstantiationException, TypeError) as err:
        raise CheckpointError(
            f"cannot rebuild the model of {path} from its saved config: {err.__cause__ or err}. "
            "It was written by an incompatible version."
        ) from err
    missing, unexpected = module.load_state_dict(state, strict=False)
    missing = [k for k in missing if not k.startswith(("euler.", "mpjpe."))]
    if missing or unexpected:
        raise CheckpointError(
            f"checkpoint {path} does not fit the rebuilt model: missing {missing[:5]}, "
            f"unexpected {unexpected[:5]}. It was written by an incompatible version."
        )
    return module.eval()


def build_test_data(cfg: DictConfig, data_cfg: DictConfig | None = None, normalizer=None):
    """The datamodule of the test windows of `data_cfg` (or `cfg.data`), set up."""
    if data_cfg is None and cfg.get("data") is None:
        raise ConfigError(
            "say whose test windows: data=h36m|cmu|synthetic (and protocol=srnn|random|strided)"
        )
    data_cfg = (cfg.data if data_cfg is None else data_cfg).copy()
    if cfg.get("protocol"):
        data_cfg.eval_protocol = cfg.protocol
    dm = build_datamodule(data_cfg, normalizer=normalizer)
    dm.prepare_data()
    dm.setup("validate")
    return dm


def build_for_evaluation(cfg: DictConfig):
    """(test windows' datamodule, module) of src.eval and src.visualize: the trained model of
    `cfg.ckpt_path` on its own data config, or the baseline `cfg.model` on `cfg.data`."""
    if cfg.ckpt_path:
        module = load_trained(cfg.ckpt_path, cfg)
        data_cfg = OmegaConf.create(module.run_info["config"]["data"])
        # Where data lives, and whether its copy lacks files, are facts of this machine.
        for key in ("data_dir", "archive_dir", "allow_partial"):
            data_cfg[key] = cfg.paths[key]
        if cfg.get("data") is not None:  # evaluation settings (protocol, windows) may differ
            for key in ("eval_protocol", "eval_windows_per_action", "eval_stride", "allow_partial"):
                data_cfg[key] = cfg.data[key]
        return build_test_data(cfg, data_cfg, module.normalizer), module
    if cfg.get("model") is None or cfg.get("data") is None:
        raise ConfigError(
            "say what to evaluate: a baseline with model=zero_velocity|running_avg_2|"
            "running_avg_4 and data=h36m|cmu, or a trained model with ckpt_path=..."
        )
    dm = build_test_data(cfg)
    config = {key: OmegaConf.to_container(cfg[key], resolve=True) for key in ("model", "data")}
    module = build_module(cfg, dm, run_info={"commit": git_commit(), "config": config})
    if module.trainable:
        raise ConfigError(
            f"model={cfg.model.name} is a trainable network and no ckpt_path was given; the "
            "numbers of an untrained network mean nothing. Train it with `python -m src.train "
            f"model={cfg.model.name} ...` and pass ckpt_path=<its checkpoint>."
        )
    return dm, module.eval()
