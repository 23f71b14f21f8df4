"""Composed Hydra configs, and checkpoints, into datamodules and the LightningModule
(src.lit.predictor.MotionPredictor): the entry points and MotionForecaster build through these
functions alone, a refusal coming before any run folder or data (`build_parts`); and the
refusals of a checkpoint that does not fit: another model or data, weights only for a resume,
other data statistics."""

from __future__ import annotations

from pathlib import Path

import hydra
import torch
from hydra.errors import InstantiationException
from omegaconf import DictConfig, OmegaConf

from src.config import ConfigError, instantiate
from src.data.normalization import Normalizer
from src.lit.checkpoints import LAST, CheckpointError, read_checkpoint
from src.lit.parts import compiled, data_facts, plain
from src.lit.predictor import MotionPredictor


def build_parts(cfg: DictConfig) -> None:
    """Build, and drop, the data module, eta schedule and optimisers (on a stand-in parameter),
    and run the network's own argument checks that need no data (`check_arguments`): their
    refusals come before the run folder is made and any data is read."""
    build_datamodule(cfg.data)
    if cfg.get("compile") is not None:
        compiled(cfg.compile.enabled, cuda=False)
    if cfg.get("sampling"):
        instantiate(cfg.sampling)
    net = OmegaConf.select(cfg, "model.net")
    checks = getattr(hydra.utils.get_class(net._target_), "check_arguments", None) if net else None
    if checks is not None:
        try:
            checks(**{**plain(net), "observed_len": cfg.data.observed_len})
        except ValueError as err:
            raise ConfigError(f"model.net.{err}") from None
    for key in ("model.optimizer", "adversarial.optimizer"):
        node = OmegaConf.select(cfg, key)
        if node is not None:
            try:
                optimizer = instantiate(node)([torch.nn.Parameter(torch.zeros(1))])
            except ValueError as err:  # torch.optim's refusal of an argument (lr < 0, ...)
                raise ConfigError(f"{key}: {err}") from None
            if not optimizer.defaults["lr"] > 0:  # torch takes 0, which trains nothing
                raise ConfigError(f"{key}.lr={node.lr} must be > 0 (with 0 nothing is trained).")


def build_datamodule(data_cfg: DictConfig, normalizer: Normalizer | None = None):
    dm = instantiate(data_cfg, _convert_="all")
    if normalizer is not None:
        dm.set_normalizer(normalizer)
    return dm


SECTIONS = ("model", "sampling", "adversarial", "metrics", "compile")


def build_module(cfg: DictConfig, dm, run_info: dict | None = None) -> MotionPredictor:
    """The LightningModule of `cfg` on `dm`, a set-up datamodule."""
    sections = {k: cfg.get(k) for k in SECTIONS}
    if cfg.model.get("optimizer") is None:  # a baseline: the regulariser's lr is the model's
        sections["adversarial"] = None
    module = MotionPredictor(
        **{k: plain(v) for k, v in sections.items()}, data=data_facts(dm), normalizer=dm.normalizer
    )
    module.run_info = run_info or {}
    return module


def load_trained(path: str | Path, cfg: DictConfig | None = None) -> MotionPredictor:
    """The one way to load a trained model: `MotionPredictor.load_from_checkpoint`, after the
    checkpoint was read with clear errors (no data file is read); in eval mode, the saved run
    config in `.run_info["config"]`. `cfg`, an evaluation config: refuse a checkpoint of
    another model= / data=; take its `metrics.dim_rule`."""
    ckpt = read_checkpoint(path)
    if cfg is not None:
        check_compatible(ckpt, cfg, path)
    if "normalizer.mean" not in ckpt["state_dict"]:
        raise CheckpointError(f"{path} holds no normaliser (normalizer.* buffers)")
    hparams = ckpt["hyper_parameters"]  # older checkpoints': from read_checkpoint's upgrade
    if cfg is not None and cfg.get("metrics") is not None:
        hparams = {**hparams, "metrics": plain(cfg.metrics)}
    try:
        module = MotionPredictor.load_from_checkpoint(
            path, map_location="cpu", weights_only=True, **hparams
        )
    except (InstantiationException, TypeError, KeyError, RuntimeError) as err:
        raise CheckpointError(
            f"cannot rebuild the model of {path} from its saved config: "
            f"{' '.join(str(err.__cause__ or err).split())[:300]}. It was written by an "
            "incompatible version."
        ) from err
    module.iterations = int(ckpt.get("global_step", 0))  # trained, for the evaluation's rows
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


def require_resumable(ckpt: dict, path: str | Path) -> None:
    if not {"optimizer_states", "loops"} <= ckpt.keys():
        raise CheckpointError(
            f"{path} holds weights only (a lean best checkpoint), not the optimiser and loop "
            f"state a resume needs; resume from the run's {LAST} instead."
        )


def check_compatible(ckpt: dict, cfg: DictConfig, path: str | Path) -> None:
    """Refuse a checkpoint whose model or data differ from what the config asks for."""
    saved, problems = ckpt["motion"]["config"], []
    model, data = cfg.get("model"), cfg.get("data")
    if model is not None and model.name != saved["model"]["name"]:
        problems.append(
            f"architecture: checkpoint is {saved['model']['name']}, config asks "
            f"for model={model.name}"
        )
    if data is not None and data.name != saved["data"]["name"]:
        problems.append(
            f"dataset: checkpoint was trained on {saved['data']['name']}, config "
            f"asks for data={data.name}"
        )
    if model is not None and not problems:
        want, have = OmegaConf.to_container(model.net, resolve=True), saved["model"]["net"]
        diff = [
            f"{k}={have[k]} in checkpoint vs {v}"
            for k, v in want.items()
            if k in have and k != "padding" and k[0] != "_" and v != have[k]
        ]
        if diff:
            problems.append("architecture settings: " + ", ".join(diff))
    if problems:
        raise CheckpointError(
            f"checkpoint {path} does not match the config: "
            + "; ".join(problems)
            + ". Drop the model=/data= overrides to use the checkpoint's own, or pick the "
            "checkpoint of the run you mean."
        )


def check_normalizer(ckpt: dict, normalizer: Normalizer, path: str | Path) -> None:
    """Refuse data whose statistics differ (the files changed since the run: its data config,
    actions included, is the run's own, src.prepare.restore_run): resuming changes the model."""
    state = ckpt["state_dict"]
    used = state["normalizer.used"]
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
