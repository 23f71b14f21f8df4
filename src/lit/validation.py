"""Checks of a composed config, before anything expensive runs: every value against the type
the code expects (src/lit/schema.py), keys added with + against the constructor they configure,
ranges, and what the machine can run."""

from __future__ import annotations

import difflib
import inspect

import hydra
from omegaconf import DictConfig, OmegaConf

from src.data.base import EVAL_PROTOCOLS
from src.lit.factory import ConfigError

# Keys of an instantiated node that are not constructor arguments: Hydra's own, and the
# dataset name (src.lit.factory.build_datamodule drops it).
_INSTANTIATE_KEYS = {"_target_", "_partial_", "_convert_", "_recursive_", "_args_"}
_NOT_PASSED = {"data": {"name"}}


def constructor_args(node: dict) -> list[str]:
    """Keyword arguments of the class a config node instantiates ([] if none or unknown)."""
    target = node.get("_target_") if isinstance(node, dict) else None
    if not isinstance(target, str):
        return []
    try:
        params = inspect.signature(hydra.utils.get_class(target)).parameters
    except Exception:  # noqa: BLE001 (an unknown target is reported where it is built)
        return []
    kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    return [name for name, p in params.items() if p.kind in kinds]


def check_constructor_keys(cfg: DictConfig) -> None:
    """Every key of an instantiated node (trainer, data, model.net, sampling, optimisers, the
    discriminator) must be an argument of its class: `+trainer.max_step=3` adds a key Hydra
    cannot check, which would otherwise fail deep inside the constructor with a TypeError."""
    plain = OmegaConf.to_container(cfg, resolve=False)
    for path, node in _instantiated_nodes(plain):
        target = hydra.utils.get_class(node["_target_"]) if _importable(node) else None
        if target is None or _takes_any_keyword(target):
            continue
        args = set(constructor_args(node))
        allowed = args | _INSTANTIATE_KEYS | _NOT_PASSED.get(path, set())
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


def _takes_any_keyword(cls) -> bool:
    try:
        params = inspect.signature(cls).parameters.values()
    except (TypeError, ValueError):
        return True
    return any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params)


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


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)


# The numbers training reads, which Hydra takes as given: a word (iterations=abc) would fail
# inside a comparison below with a traceback, and int() would truncate iterations=1.5 to 1.
_WHOLE_NUMBERS = (
    "iterations",
    "val_every",
    "seed",
    "checkpoint_every",
    "media_every",
    "data.batch_size",
    "data.future_len",
    "data.observed_len",
    "model.net.C",
    "model.lr_decay_every",
    "sampling.steps",
)
_NUMBERS = (
    "progress_every_s",
    "model.optimizer.lr",
    "model.lambda_2",
    "model.lr_decay_gamma",
    "model.grad_clip_norm",
    "adversarial.optimizer.lr",
    "adversarial.lambda_adv",
    "adversarial.lambda_2",
    "sampling.eta",
    "sampling.start",
    "sampling.end",
    "sampling.k",
)


def check_number_types(
    cfg: DictConfig,
    whole_numbers: tuple[str, ...],
    numbers: tuple[str, ...] = (),
    optional: bool = True,
) -> None:
    """Each of these keys holds a whole number, or a number (ConfigError if not); with
    `optional`, a key that is unset or null is let through."""
    for key in whole_numbers + numbers:
        value = OmegaConf.select(cfg, key, default=None)
        if value is None and optional:
            continue
        whole = isinstance(value, int) and not isinstance(value, bool)
        if key in whole_numbers:
            _require(whole, f"{key}={value!r} must be a whole number.")
        else:
            _require(whole or isinstance(value, float), f"{key}={value!r} must be a number.")


def validate_train_config(cfg: DictConfig) -> None:
    """Out-of-range values are rejected here, naming the allowed range."""
    check_trainable(cfg)  # first: a baseline's config lacks what the checks below read
    check_constructor_keys(cfg)
    check_number_types(cfg, _WHOLE_NUMBERS, _NUMBERS)
    _require(cfg.iterations > 0, f"iterations={cfg.iterations} must be a positive integer.")
    seed = cfg.get("seed")
    if seed is not None:  # Lightning's seed_everything would raise numpy's range error
        _require(0 <= seed < 2**32, f"seed={seed} must lie in [0, 2**32 - 1].")
    every = cfg.get("checkpoint_every")
    if every is not None:
        # A negative period divides every iteration: last.ckpt would be written at each one.
        _require(every >= 0, f"checkpoint_every={every} must be >= 0 iterations (0: off).")
    compile_on = cfg.get("compile", {}).get("enabled", "auto")
    _require(
        compile_on in (True, False, "auto"),
        f"compile.enabled={compile_on!r}: use true, false or auto (on a CUDA device).",
    )
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
    _check_dim_rule(cfg)


def validate_eval_config(cfg: DictConfig) -> None:
    """The evaluation settings that do not come from a checkpoint."""
    check_constructor_keys(cfg)
    _check_dim_rule(cfg)
    _check_protocol("protocol", cfg.get("protocol"))


def _check_dim_rule(cfg: DictConfig) -> None:
    rule = cfg.metrics.dim_rule
    _require(rule in ("future", "window"), f"metrics.dim_rule={rule!r}: use future or window.")


def _check_protocol(key: str, protocol: str | None) -> None:
    if protocol is not None:
        _require(
            protocol in EVAL_PROTOCOLS,
            f"{key}={protocol!r} is unknown; use one of: " + ", ".join(EVAL_PROTOCOLS),
        )
