"""The type of every key of the entry points' configs, each declared once, and the check of a
composed config against them.

Hydra reads a command-line value as YAML-like text and the configs are untyped, so a value
arrives as whatever it parses to: `model.net.long_term=no` is the string 'no', which Python
takes as true, and an ablation would silently run the full model. Here every value is checked
against its type before anything runs:

- a key of a node that Hydra instantiates (`_target_`: the trainer, the data module, the
  networks, the optimisers, the eta schedule) has the type of its constructor's annotation;
- every other key is declared below, in the TypedDicts of the config it belongs to.

A key that neither declares (`+iteratons=100`, which Hydra adds without a word) is refused too.
"""

from __future__ import annotations

import collections.abc
import difflib
import inspect
import os
import types
import typing
from typing import Any, Literal, TypedDict, Union

import hydra
from omegaconf import DictConfig, OmegaConf

from src.data.base import EVAL_PROTOCOLS
from src.lit.factory import ConfigError
from src.metrics.euler_error import DIM_RULES

# A node Hydra instantiates: its keys are typed by the constructor of its `_target_`.
Instantiated = dict[str, Any]
# Keys of an instantiated node that are not constructor arguments: Hydra's own, with the types
# hydra.utils.instantiate reads them as (a '_partial_: no' would be true).
INSTANTIATE_TYPES = {
    "_target_": str,
    "_partial_": bool,
    "_convert_": Literal["none", "partial", "object", "all"],
    "_recursive_": bool,
    "_args_": list,
}
INSTANTIATE_KEYS = set(INSTANTIATE_TYPES)


class Paths(TypedDict, total=False):
    root_dir: str
    archive_dir: str | None
    data_dir: str
    log_dir: str
    output_dir: str


class Data(TypedDict, total=False):  # and the arguments of its data module
    name: str  # not passed: src.lit.factory.build_datamodule drops it


class Model(TypedDict, total=False):  # read by src.lit.factory.build_module
    name: str
    net: Instantiated
    optimizer: Instantiated
    lr_decay_every: int
    lr_decay_gamma: float
    lambda_2: float
    grad_clip_norm: float | None
    published: dict | None  # src.reporting.published.published_for


class Adversarial(TypedDict, total=False):  # read by src.lit.factory.build_module
    enabled: bool
    lambda_adv: float
    lambda_2: float
    reference_fake_slot: bool
    discriminator: Instantiated
    optimizer: Instantiated


class Metrics(TypedDict, total=False):
    dim_rule: Literal[DIM_RULES]


class Compile(TypedDict, total=False):
    enabled: bool | Literal["auto"]
    mode: str  # torch.compile's mode


class _Common(TypedDict, total=False):  # the keys of every entry point's config
    task_name: str
    run_name: str
    seed: int | None
    val_every: int
    ckpt_path: str | None
    paths: Paths
    data: Data | None  # null in eval and visualize until chosen (a checkpoint brings its own)
    model: Model | None
    sampling: Instantiated | None
    adversarial: Adversarial | None
    trainer: Instantiated
    metrics: Metrics


class TrainConfig(_Common, total=False):  # conf/train.yaml
    iterations: int
    resume: str | None
    checkpoint_every: int
    media_every: int
    progress_every_s: float | None
    compile: Compile


class EvalConfig(_Common, total=False):  # conf/eval.yaml
    protocol: Literal[EVAL_PROTOCOLS] | None
    predictions: str | None  # a .npz of predictions from any code (src/scoring.py)
    published: str | None  # PAPER:METHOD or none


class ExportWindowsConfig(_Common, total=False):  # conf/export_windows.yaml
    protocol: Literal[EVAL_PROTOCOLS] | None
    out: str | None


class VisualizeConfig(_Common, total=False):  # conf/visualize.yaml
    action: str
    window: int
    baseline: bool
    format: Literal["gif", "mp4"]
    observed_shown: int
    strip_step: int


SCHEMAS = {
    "train": TrainConfig,
    "eval": EvalConfig,
    "visualize": VisualizeConfig,
    "export_windows": ExportWindowsConfig,
}


# ------------------------------------------------------------------------------ the check
def check_types(cfg: DictConfig, schema: type) -> None:
    """Every value of `cfg` (Hydra's own node left out) has its declared type, and every key
    is declared; ConfigError naming the first that is not, and what it must be."""
    interpolated: list[tuple[str, Any]] = []
    _check_node(cfg, OmegaConf.to_container(cfg, resolve=False), "", schema, interpolated)
    # Last, so that a wrong value is named at the key the user set, not at a copy of it.
    for key, annotation in interpolated:
        _check_value(cfg, key, annotation)


def declared_types(node: dict, schema: type | None) -> dict[str, Any]:
    """Key -> type of a config node: its TypedDict's, and the constructor's arguments for an
    instantiated node."""
    hints = typing.get_type_hints(schema) if schema is not None else {}
    target = node.get("_target_")
    if isinstance(target, str):
        try:
            arguments = constructor_types(hydra.utils.get_class(target))
        except Exception:  # noqa: BLE001 (an unknown target is reported where it is built)
            arguments = None
        if arguments is None:
            return {}
        hints = {**arguments, **hints, **INSTANTIATE_TYPES}
    return hints


def constructor_types(cls: type) -> dict[str, Any] | None:
    """The keyword arguments of `cls` and their annotations (Any where there is none); through
    **kwargs, those of the base class it passes them to. None if it takes any keyword."""
    out: dict[str, Any] = {}
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        try:
            params = inspect.signature(init).parameters.values()
        except (TypeError, ValueError):
            return None
        try:
            hints = typing.get_type_hints(init)
        except Exception:  # noqa: BLE001 (an annotation that does not resolve: no type known)
            hints = {}
        for p in params:
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name != "self":
                out.setdefault(p.name, hints.get(p.name, Any))
        if not any(p.kind is p.VAR_KEYWORD for p in params):
            return out
    return None  # **kwargs all the way up: any keyword is taken


_UNRESOLVED = object()


def _check_node(
    cfg: DictConfig, node: dict, path: str, schema: type | None, interpolated: list
) -> None:
    declared = declared_types(node, schema)
    instantiated = isinstance(node.get("_target_"), str)
    for key, raw in node.items():
        here = f"{path}.{key}" if path else str(key)
        if here == "hydra":
            continue
        if key not in declared:
            if instantiated or not declared:
                continue  # validation.check_constructor_keys names it, with the arguments
            close = difflib.get_close_matches(str(key), list(declared), n=3, cutoff=0.6)
            hint = f" Did you mean {' or '.join(close)}?" if close else ""
            where = f"under {path}" if path else "at the top level"
            raise ConfigError(
                f"{here}: no such setting {where}, so nothing would read it (a + adds only "
                f"what the code takes).{hint} Settings {where}: {', '.join(sorted(declared))}."
            )
        annotation = declared[key]
        if isinstance(raw, dict) and raw:
            sub = _typed_dict(annotation)
            if sub is not None or "_target_" in raw:
                _check_node(cfg, raw, here, sub, interpolated)
                continue
        if isinstance(raw, str) and "${" in raw:
            interpolated.append((here, annotation))
        else:
            _check_value(cfg, here, annotation)


def _check_value(cfg: DictConfig, key: str, annotation: Any) -> None:
    value = _resolved(cfg, key)
    if value is not _UNRESOLVED and not conforms(value, annotation):
        raise ConfigError(f"{key}={value!r} must be {describe(annotation)}.")


def _typed_dict(annotation: Any) -> type | None:
    if typing.is_typeddict(annotation):
        return annotation
    for arg in typing.get_args(annotation):
        if typing.is_typeddict(arg):
            return arg
    return None


def _resolved(cfg: DictConfig, key: str) -> Any:
    """The value at `key`, interpolations resolved; _UNRESOLVED for one that points at state
    not set up yet (the run folder, `${hydra:...}`): it is not the user's text."""
    try:
        value = OmegaConf.select(cfg, key, throw_on_missing=True)
        return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value
    except Exception:  # noqa: BLE001
        return _UNRESOLVED


def _union(annotation: Any) -> bool:
    return typing.get_origin(annotation) in (Union, types.UnionType)


def conforms(value: Any, annotation: Any) -> bool:
    """Whether a config value (None, bool, int, float, str, list, dict) has the type
    `annotation`. bool is not taken for a number, nor a number for a bool; an int is a
    float; a string a path. Annotations this check does not know let the value through."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if annotation in (Any, inspect.Parameter.empty):
        return True
    if _union(annotation):
        return any(conforms(value, a) for a in args)
    if origin is Literal:
        return any(type(value) is type(a) and value == a for a in args)
    if annotation in (None, type(None)):
        return value is None
    if annotation is bool:
        return isinstance(value, bool)
    if annotation is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if annotation is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if annotation is str:
        return isinstance(value, str)
    if annotation is os.PathLike or (
        isinstance(annotation, type) and issubclass(annotation, os.PathLike)
    ):
        return isinstance(value, str)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(conforms(v, args[0]) for v in value)
        return len(value) == len(args) and all(
            conforms(v, a) for v, a in zip(value, args, strict=True)
        )
    if origin in (list, set, collections.abc.Iterable, collections.abc.Sequence):
        return isinstance(value, (list, tuple)) and all(conforms(v, args[0]) for v in value)
    if annotation is dict or origin is dict or typing.is_typeddict(annotation):
        return isinstance(value, dict)
    if isinstance(annotation, type):
        return isinstance(value, annotation)
    return True


def describe(annotation: Any) -> str:
    """What a value of `annotation` is, in words: "a whole number or null", "true or false"."""
    words = list(dict.fromkeys(_words(annotation)))
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]


def _words(annotation: Any) -> list[str]:
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if _union(annotation):
        # Alternatives a config cannot hold (a Tensor, an Accelerator object) are left out.
        words = [w for a in args for w in _words(a) if w]
        return words or ["a value"]
    if origin is Literal:
        return [str(a) for a in args]
    simple = {type(None): "null", None: "null", int: "a whole number", float: "a number"}
    if annotation in simple:
        return [simple[annotation]]
    if annotation is bool:
        return ["true", "false"]
    if annotation is str or annotation is os.PathLike:
        return ["a string"]
    if origin is tuple and args and args[-1] is not Ellipsis:
        of = {int: "whole numbers", float: "numbers"}.get(args[0], "values")
        return [f"a list of {len(args)} {of}"]
    if origin in (tuple, list, set, collections.abc.Iterable, collections.abc.Sequence):
        return ["a list"]
    if annotation is dict or origin is dict:
        return ["a mapping"]
    return [""]
