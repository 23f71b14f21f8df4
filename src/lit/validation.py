"""Checks a composed config before anything expensive runs, and turns the project's own errors
into one clear line instead of a traceback."""

from __future__ import annotations

import functools
import logging
import sys

from omegaconf import DictConfig

from src.data.base import EVAL_PROTOCOLS
from src.data.errors import DataError
from src.lit.checkpoints import CheckpointError
from src.lit.factory import ConfigError
from src.lit.predictor import NonFiniteLossError

log = logging.getLogger("src")

USER_ERRORS = (DataError, ConfigError, CheckpointError, NonFiniteLossError)


def friendly_errors(fn):
    """Print the project's own errors as one message and exit with status 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except USER_ERRORS as err:
            print(f"error: {err}", file=sys.stderr)
            sys.exit(2)

    return wrapper


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)


def validate_train_config(cfg: DictConfig) -> None:
    """Out-of-range values are rejected here, naming the allowed range."""
    _require(cfg.iterations > 0, f"iterations={cfg.iterations} must be a positive integer.")
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
