"""Checks a composed config before anything expensive runs, and turns the project's own errors
into one clear line instead of a traceback.

`hydra_entry` is the decorator of the Hydra entry points (train, eval, visualize): it checks that
the configs exist (a non-editable install has none), runs Hydra, and prints what Hydra rejects
before the task starts (a misspelt key or option, an unparsable override) as one line naming the
close matches; `friendly_errors` does the same for the project's errors raised by the task.
"""

from __future__ import annotations

import difflib
import functools
import inspect
import logging
import os
import sys
from pathlib import Path

import hydra
from hydra.errors import (
    ConfigCompositionException,
    MissingConfigException,
    OverrideParseException,
    SearchPathException,
)
from omegaconf import DictConfig, OmegaConf

from src.data.base import EVAL_PROTOCOLS
from src.data.errors import DataError
from src.lit.checkpoints import CheckpointError
from src.lit.factory import PROJECT_ROOT, ConfigError
from src.lit.predictor import NonFiniteLossError

log = logging.getLogger("src")

USER_ERRORS = (DataError, ConfigError, CheckpointError, NonFiniteLossError)
# What Hydra raises while it composes the config from the command line, before the task runs.
HYDRA_USER_ERRORS = (ConfigCompositionException, OverrideParseException, SearchPathException)
CONF_DIR = PROJECT_ROOT / "conf"
# Keys of an instantiated node that are not constructor arguments: Hydra's own, and the
# dataset name (src.lit.factory.build_datamodule drops it).
_INSTANTIATE_KEYS = {"_target_", "_partial_", "_convert_", "_recursive_", "_args_"}
_NOT_PASSED = {"data": {"name"}}


def _print_error(message: object) -> None:
    """What a user sees instead of a traceback: `error: <what is wrong and the fix>`."""
    print(f"error: {message}", file=sys.stderr)


def friendly_errors(fn):
    """Print the project's own errors as one message and exit with status 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except USER_ERRORS as err:
            _print_error(err)
            sys.exit(2)

    return wrapper


def check_installation(conf_dir: Path | None = None) -> None:
    """The configs live in conf/ beside the package in the clone; `pip install .` (not
    editable) copies only the package into site-packages, where Hydra then finds no configs."""
    conf_dir = CONF_DIR if conf_dir is None else conf_dir
    if not (conf_dir / "train.yaml").is_file():
        raise ConfigError(
            f"the project's configs are missing: {conf_dir} holds no train.yaml, so the package "
            f"was run from {PROJECT_ROOT / 'src'} without the clone it belongs to (as after "
            "`pip install .`, which copies only the Python code). Fix: `pip uninstall "
            "motion-forecast`, then install from the clone with `pip install -e .` (editable) "
            "and run the commands there."
        )


def hydra_entry(config_name: str):
    """`@hydra.main` for `conf/<config_name>.yaml` with the project's one-line errors.

    Replaces the pair `@hydra.main(version_base="1.3", config_path="../conf", config_name=...)`
    and `@friendly_errors`. Hydra's own messages for a misspelt key, a misspelt option or an
    unparsable override span several lines without the valid keys; here they become one line
    naming the close matches. HYDRA_FULL_ERROR=1 still shows Hydra's full traceback.
    """

    def decorate(fn):
        task = friendly_errors(fn)

        @functools.wraps(fn)
        def entry(cfg_passthrough: DictConfig | None = None):
            if cfg_passthrough is not None:
                return task(cfg_passthrough)
            try:
                check_installation()
            except ConfigError as err:
                _print_error(err)
                sys.exit(2)
            run = hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name=config_name)
            if os.environ.get("HYDRA_FULL_ERROR") == "1":
                return run(task)()
            # Hydra prints composition errors itself and exits, unless HYDRA_FULL_ERROR is set:
            # then it raises them, and they are reported here.
            os.environ["HYDRA_FULL_ERROR"] = "1"
            try:
                return run(task)()
            except HYDRA_USER_ERRORS as err:
                _print_error(describe_hydra_error(err, config_name, _command_line_overrides()))
                sys.exit(2)
            finally:
                os.environ.pop("HYDRA_FULL_ERROR", None)

        return entry

    return decorate


def _command_line_overrides() -> list[str]:
    return [a for a in sys.argv[1:] if not a.startswith("-")]


def describe_hydra_error(err: Exception, config_name: str, overrides: list[str]) -> str:
    """One line for an error Hydra raised while composing `config_name` with `overrides`."""
    text = str(err)
    if isinstance(err, OverrideParseException):
        return (
            f"cannot parse the override {err.override!r}: {err.message.splitlines()[0]}. Fix: "
            "write key=value; quote a value holding '=', ',', spaces or brackets, e.g. "
            "\"ckpt_path='a=b,c/last.ckpt'\"."
        )
    if isinstance(err, MissingConfigException) and err.options is not None:
        group = os.path.dirname(err.missing_cfg_file or "") or "?"
        wanted = os.path.basename(err.missing_cfg_file or "")
        close = difflib.get_close_matches(wanted, err.options, n=3, cutoff=0.5)
        hint = f" Did you mean {group}={' or '.join(close)}?" if close else ""
        return (
            f"{group}={wanted}: no such option of {config_name}.{hint} Choose one of: "
            f"{', '.join(sorted(err.options))}."
        )
    if text.startswith("Could not override '"):
        key = text[len("Could not override '") :].split("'", 1)[0]
        config = _compose_without(config_name, overrides, key)
        return unknown_key_message(key, config, groups=config_groups(config_name))
    if text.startswith("Could not append to config. An item is already at '"):
        key = text.split("'")[1]
        return (
            f"+{key}: the config already has {key}; set it without the +: {key}=<value> "
            f"(`python -m src.{config_name} --help` lists the settings)."
        )
    return f"{' '.join(text.split())} (`python -m src.{config_name} --help` lists the settings)"


def _compose_without(config_name: str, overrides: list[str], key: str) -> dict | None:
    """The config composed from the other overrides (to find the keys that do exist), as a
    plain unresolved dict; None if it cannot be composed."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    def key_of(override: str) -> str:
        return override.split("=", 1)[0].lstrip("+~")

    others = [o for o in overrides if key_of(o) != key and "=" in o]
    # A sweep (a,b) or a misspelt neighbour must not hide the keys: fall back to fewer overrides.
    choices = [o for o in others if "." not in key_of(o) and "," not in o]
    for attempt in (others, choices, []):
        GlobalHydra.instance().clear()
        try:
            with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
                cfg = compose(config_name, overrides=attempt)
            return OmegaConf.to_container(cfg, resolve=False)
        except Exception:  # noqa: BLE001 (any failure: try with fewer overrides)
            continue
        finally:
            GlobalHydra.instance().clear()
    return None


def config_groups(config_name: str) -> list[str]:
    """The config groups `conf/<config_name>.yaml` composes (its defaults list, Hydra's own
    left out): the options a `group=option` override may name."""
    try:
        primary = OmegaConf.to_container(OmegaConf.load(CONF_DIR / f"{config_name}.yaml"))
        defaults = primary.get("defaults") or []
    except Exception:  # noqa: BLE001 (only the suggestions are lost)
        return []
    groups = []
    for entry in defaults:
        name = next(iter(entry)) if isinstance(entry, dict) else str(entry).split(":")[0]
        name = name.split()[-1]  # "optional experiment", "override /model"
        if name not in ("_self_", "hydra") and not name.startswith("hydra/"):
            groups.append(name.lstrip("/"))
    return groups


def unknown_key_message(key: str, config: dict | None, groups: list[str] = ()) -> str:
    """`key` is not in `config` (a plain dict): name the closest keys that exist, including
    constructor arguments of an instantiated node that the config leaves out (added with +)
    and, at the top level, the config `groups` (which a baseline config may leave empty)."""
    parts = key.split(".")
    node, depth = config or {}, 0
    while depth < len(parts) and isinstance(node, dict) and parts[depth] in node:
        node, depth = node[parts[depth]], depth + 1
    prefix, rest = parts[:depth], parts[depth + 1 :]
    where = ".".join(prefix) or "the top level"
    if depth == 0 and rest and parts[0] in groups:
        # A group the config leaves empty (eval's data and model: a checkpoint brings its
        # own): its keys exist once an option is chosen, so naming the key itself as the
        # close match would not help.
        group = parts[0]
        options = "|".join(sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml")))
        return (
            f"{key}: no {group} option is chosen, so there is no {key} to set. Choose one "
            f"before it: {group}={options} {key}=<value> (with ckpt_path=, the checkpoint's "
            f"own {group})."
        )
    if not isinstance(node, dict):
        return (
            f"{key}: {'.'.join(prefix)} is a value, not a group of settings, so it has no "
            f"{'.'.join(parts[depth:])}. Set {'.'.join(prefix)}=<value>."
        )
    present = [str(k) for k in node if not str(k).startswith("_")]
    if depth == 0:
        present += [g for g in groups if g not in present]
    addable = [a for a in _constructor_args(node) if a not in node]
    wanted = parts[depth]
    candidates = present + addable
    if rest:  # the key goes deeper: only a group of settings (or a config group) can match
        candidates = [c for c in present if isinstance(node.get(c), dict) or c in groups]
    close = difflib.get_close_matches(wanted, candidates, n=3, cutoff=0.6)

    def spell(name: str) -> str:
        full = ".".join([*prefix, name, *rest])
        return f"+{full}" if name in addable else full

    hint = f"Did you mean {' or '.join(spell(c) for c in close)}? " if close else ""
    added = ""
    if any(c in addable for c in close):
        added = " (+ adds an argument the config leaves out)"
    shown = ", ".join(sorted(present)[:40])
    return f"{key}: no such key. {hint}Keys under {where}: {shown}{added}."


def _constructor_args(node: dict) -> list[str]:
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
        args = set(_constructor_args(node))
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
