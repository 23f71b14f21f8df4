"""Checks of a composed config, before anything expensive runs: every value against the type
the code expects (src/lit/schema.py), keys added with + against the constructor they configure,
ranges, and what the machine can run."""

from __future__ import annotations

import difflib
import typing

import hydra
import torch
from omegaconf import DictConfig, OmegaConf

from src.data.base import EVAL_PROTOCOLS
from src.lit.factory import ConfigError
from src.lit.schema import (
    INSTANTIATE_KEYS,
    Data,
    EvalConfig,
    TrainConfig,
    check_types,
    constructor_types,
)

# Keys of a data node that are not data module arguments (the dataset's name).
_NOT_PASSED = {"data": set(typing.get_type_hints(Data))}


def constructor_args(node: dict) -> list[str]:
    """Keyword arguments of the class a config node instantiates ([] if none or unknown)."""
    target = node.get("_target_") if isinstance(node, dict) else None
    if not isinstance(target, str) or not _importable(node):
        return []
    return list(constructor_types(hydra.utils.get_class(target)) or [])


def check_constructor_keys(cfg: DictConfig) -> None:
    """Every key of an instantiated node (trainer, data, model.net, sampling, optimisers, the
    discriminator) must be an argument of its class: `+trainer.max_step=3` adds a key Hydra
    cannot check, which would otherwise fail deep inside the constructor with a TypeError."""
    plain = OmegaConf.to_container(cfg, resolve=False)
    for path, node in _instantiated_nodes(plain):
        if not _importable(node):
            continue  # reported where it is built
        if constructor_types(hydra.utils.get_class(node["_target_"])) is None:
            continue  # **kwargs all the way: any key is taken
        args = set(constructor_args(node))
        allowed = args | INSTANTIATE_KEYS | _NOT_PASSED.get(path, set())
        for key in node:
            if key not in allowed:
                close = difflib.get_close_matches(str(key), sorted(args), n=3, cutoff=0.6)
                if close:
                    fix = "Did you mean " + " or ".join(f"{path}.{c}" for c in close) + "?"
                else:
                    fix = f"Its arguments: {', '.join(sorted(args))}."
                raise ConfigError(
                    f"{path}.{key} is not an argument of {node['_target_']}, so it cannot be "
                    f"added. {fix}"
                )


def _importable(node: dict) -> bool:
    try:
        hydra.utils.get_class(node["_target_"])
        return True
    except Exception:  # noqa: BLE001 (reported where it is built)
        return False


def _instantiated_nodes(tree: dict, path: str = ""):
    for key, value in tree.items():
        if key == "hydra" or not isinstance(value, dict):
            continue
        here = f"{path}.{key}" if path else str(key)
        if isinstance(value.get("_target_"), str):
            yield here, value
        else:
            yield from _instantiated_nodes(value, here)


def check_trainable(cfg: DictConfig) -> None:
    """A baseline (zero-velocity, running average) has no weights: training it is refused
    before anything else, with the command that evaluates it instead."""
    target = OmegaConf.select(cfg, "model.net._target_", default=None)
    if not isinstance(target, str) or not _importable({"_target_": target}):
        return
    if getattr(hydra.utils.get_class(target), "trainable", True) is False:
        name = OmegaConf.select(cfg, "model.name", default=target)
        data = OmegaConf.select(cfg, "data.name", default="h36m")
        raise ConfigError(
            f"{name} has no trainable parameters, so there is nothing to train; evaluate it with "
            f"`python -m src.eval model={name} data={data}` instead."
        )


def check_accelerator(cfg: DictConfig) -> None:
    """A GPU asked for where torch finds none: Lightning's own error ("No supported gpu backend
    found!") comes as a traceback, after the data has loaded."""
    from lightning.pytorch.accelerators import CUDAAccelerator, MPSAccelerator

    accelerator = OmegaConf.select(cfg, "trainer.accelerator", default=None)
    wanted = {"gpu": (CUDAAccelerator, MPSAccelerator), "cuda": (CUDAAccelerator,),
              "mps": (MPSAccelerator,)}.get(accelerator, ())  # fmt: skip
    if not wanted or any(kind.is_available() for kind in wanted):
        return
    build = " (a CPU-only build)" if torch.version.cuda is None else ""
    raise ConfigError(
        f"trainer.accelerator={accelerator} asks for a GPU, and torch {torch.__version__}"
        f"{build} finds none on this machine. Run on the CPU with trainer=cpu, or leave "
        "trainer= out: trainer=default takes a GPU where there is one."
    )


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)


def validate_train_config(cfg: DictConfig) -> None:
    """Out-of-range values are rejected here, naming the allowed range."""
    check_trainable(cfg)  # first: a baseline's config lacks what the checks below read
    check_constructor_keys(cfg)
    check_types(cfg, TrainConfig)  # then the comparisons below compare numbers
    check_accelerator(cfg)
    _require(cfg.iterations > 0, f"iterations={cfg.iterations} must be a positive integer.")
    seed = cfg.get("seed")
    if seed is not None:  # Lightning's seed_everything would raise numpy's range error
        _require(0 <= seed < 2**32, f"seed={seed} must lie in [0, 2**32 - 1].")
    every = cfg.get("checkpoint_every")
    if every is not None:
        # A negative period divides every iteration: last.ckpt would be written at each one.
        _require(every >= 0, f"checkpoint_every={every} must be >= 0 iterations (0: off).")
    _require(cfg.val_every > 0, f"val_every={cfg.val_every} must be a positive integer.")
    _require(cfg.data.batch_size > 0, f"data.batch_size={cfg.data.batch_size} must be > 0.")
    _require(cfg.data.future_len >= 1, f"data.future_len={cfg.data.future_len} must be >= 1 frame.")
    lr = cfg.model.get("optimizer", {}).get("lr") if cfg.get("model") else None
    if lr is not None:
        _require(lr > 0, f"model.optimizer.lr={lr} must be a positive learning rate.")
    adv = cfg.get("adversarial")
    if adv is not None and adv.get("enabled") and adv.get("optimizer") is not None:
        _require(adv.optimizer.lr > 0, f"adversarial.optimizer.lr={adv.optimizer.lr} must be > 0.")
        _require(adv.lambda_adv >= 0, f"adversarial.lambda_adv={adv.lambda_adv} must be >= 0.")
    for key in ("eta", "start", "end"):
        value = cfg.get("sampling", {}).get(key)
        if value is not None:
            _require(
                0.0 <= value <= 1.0,
                f"sampling.{key}={value} is outside [0, 1]; eta mixes prediction (1) and "
                "ground truth (0).",
            )
    C = cfg.model.net.get("C") if cfg.get("model") else None
    if C is not None:
        _require(
            1 <= C <= cfg.data.observed_len,
            f"model.net.C={C} must be between 1 and data.observed_len={cfg.data.observed_len} "
            "(the short-term window lies inside the observed frames).",
        )
    model = cfg.get("model") or {}
    if model.get("lambda_2") is not None:
        _require(model.lambda_2 >= 0, f"model.lambda_2={model.lambda_2} must be >= 0.")
    if adv is not None and adv.get("enabled") and adv.get("lambda_2") is not None:
        _require(adv.lambda_2 >= 0, f"adversarial.lambda_2={adv.lambda_2} must be >= 0.")
    every, gamma = model.get("lr_decay_every"), model.get("lr_decay_gamma")
    if every is not None:
        _require(every >= 1, f"model.lr_decay_every={every} must be >= 1 iteration.")
    if gamma is not None:
        _require(0 < gamma <= 1, f"model.lr_decay_gamma={gamma} must be in (0, 1].")
    clip = model.get("grad_clip_norm")
    if clip is not None:
        _require(clip > 0, f"model.grad_clip_norm={clip} must be > 0, or null for no clipping.")
    sampling = cfg.get("sampling") or {}
    if sampling.get("steps") is not None:
        _require(sampling.steps >= 1, f"sampling.steps={sampling.steps} must be >= 1.")
    if sampling.get("k") is not None:
        _require(sampling.k >= 1, f"sampling.k={sampling.k} must be >= 1.")
    _check_protocol("data.eval_protocol", cfg.data.get("eval_protocol"))


def validate_eval_config(cfg: DictConfig, schema: type = EvalConfig) -> None:
    """The evaluation settings that do not come from a checkpoint (src.visualize's, with its
    own `schema`)."""
    check_constructor_keys(cfg)
    check_types(cfg, schema)
    check_accelerator(cfg)
    if cfg.get("data") is not None:
        _check_protocol("data.eval_protocol", cfg.data.get("eval_protocol"))


def _check_protocol(key: str, protocol: str | None) -> None:
    if protocol is not None:
        _require(
            protocol in EVAL_PROTOCOLS,
            f"{key}={protocol!r} is unknown; use one of: " + ", ".join(EVAL_PROTOCOLS),
        )


def check_schedule(cfg: DictConfig) -> None:
    """Training runs whole validation periods: `iterations` must be a multiple of `val_every`,
    or the run would silently train more (or fewer) iterations than asked."""
    iterations, every = int(cfg.iterations), int(cfg.val_every)
    if iterations <= 0 or every <= 0 or iterations % every == 0:
        return  # non-positive values are named by validate_train_config
    lower = iterations // every * every
    lengths = " or ".join(f"iterations={n}" for n in (lower, lower + every) if n > 0)
    divisor = max(d for d in range(1, every + 1) if iterations % d == 0)
    raise ConfigError(
        f"iterations={iterations} is not a multiple of val_every={every} (training runs whole "
        f"validation periods); use {lengths}, or val_every={divisor}."
    )
