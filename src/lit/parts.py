"""What a MotionPredictor is built from: its config sections as plain containers (the
checkpoint's hyper-parameters), the facts of its data (`data_facts`), its networks (`network`)
and the compile setting (`compiled`)."""

from __future__ import annotations

import inspect
from typing import Any

import hydra
from omegaconf import DictConfig, ListConfig, OmegaConf

from src.config import ConfigError, instantiate
from src.data.normalization import Normalizer


def compiled(setting: Any, cuda: bool, name: str = "compile.enabled") -> bool:
    """Whether a compile setting (true, false or auto: on a CUDA device only) compiles here."""
    if not (isinstance(setting, bool) or setting == "auto"):
        raise ConfigError(f"{name}={setting!r} must be true, false or auto (auto: on CUDA only).")
    return setting is True or (setting == "auto" and cuda)


def plain(node) -> Any:
    """A config node as plain containers (what a checkpoint can hold and load weights-only)."""
    if isinstance(node, (DictConfig, ListConfig)):
        return OmegaConf.to_container(node, resolve=True)
    return node


def data_facts(dm) -> dict[str, Any]:
    """What a model needs of its set-up datamodule, kept with it so that it is rebuilt without
    any data file: dataset, actions, lengths, padding (protocol §6.7), the used columns."""
    return {
        "dataset": dm.dataset_name,
        "actions": list(dm.actions),
        "untrained_actions": list(dm.untrained_actions),
        "observed_len": dm.observed_len,
        "future_len": dm.future_len,
        "frame_ms": dm.frame_ms,
        "conv_padding": dm.conv_padding,
        "used": dm.normalizer.dim_used.tolist(),
        "num_features": dm.normalizer.num_features,
    }


def network(node, facts: dict[str, Any], normalizer: Normalizer, **extra):
    """A network of the config node, with what only the data knows."""
    kwargs: dict[str, Any] = {
        "pose_dim": len(facts["used"]), "num_actions": len(facts["actions"]), **extra
    }  # fmt: skip
    params = inspect.signature(hydra.utils.get_class(node["_target_"])).parameters
    if "normalizer" in params:
        kwargs["normalizer"] = normalizer
    if "observed_len" in params:  # ConvSeq2Seq checks its C against it
        kwargs["observed_len"] = facts["observed_len"]
    if node.get("padding") == "auto":
        kwargs["padding"] = facts["conv_padding"]
    return instantiate(node, **kwargs, _convert_="all")
