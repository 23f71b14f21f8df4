"""The types of the entry points' configs and the checks of a composed config: a node Hydra
instantiates (`_target_`) is typed by its constructor's signature (hydra-zen's `builds`), every
other key by the dataclasses below; OmegaConf checks both, this module the ranges (`within`) of
keys no constructor reads and a few combinations."""

import contextlib
import dataclasses
import difflib
import functools
import inspect
import types
import typing
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Union

import hydra
import torch
from hydra_zen import BuildsFn
from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, OmegaConfBaseException
from omegaconf.nodes import AnyNode, BooleanNode, EnumNode, FloatNode, IntegerNode, StringNode

from src.data.base import EVAL_PROTOCOLS
from src.metrics.euler_error import DIM_RULES


class ConfigError(ValueError):
    """A configuration value or combination that cannot work."""


def within(low: float, high: float | None = None, *, above: bool = False) -> Any:
    """A field whose value must lie in [low, high] ((low, high] with above=True)."""
    return field(metadata={"range": (low, high, above)})


DimRule = Enum("DimRule", DIM_RULES)
Protocol = Enum("Protocol", EVAL_PROTOCOLS)
Format = Enum("Format", ("gif", "mp4"))


@dataclass
class Paths:
    root_dir: str
    archive_dir: str | None
    data_dir: str
    allow_partial: bool  # this machine's data copy lacks files (MOTION_ALLOW_PARTIAL)
    log_dir: str
    output_dir: str


@dataclass
class Model:  # read by src.lit.factory.build_module
    name: str
    net: Any  # typed by its _target_, as the optimiser
    optimizer: Any
    lr_decay_every: int = within(1)
    lr_decay_gamma: float = within(0, 1, above=True)
    lambda_2: float = within(0)
    grad_clip_norm: float | None = within(0, above=True)
    published: Any  # src.reporting.published.published_for


@dataclass
class Adversarial:  # read by src.lit.factory.build_module
    enabled: bool
    lambda_adv: float = within(0)
    lambda_2: float = within(0)
    reference_fake_slot: bool
    discriminator: Any
    optimizer: Any


@dataclass
class Metrics:
    dim_rule: DimRule


@dataclass
class Compile:
    enabled: Any  # true, false or auto: checked by name below
    mode: str  # torch.compile's


@dataclass
class Common:  # the keys of every entry point's config
    task_name: str
    run_name: str
    seed: int | None = within(0, 2**32 - 1)  # numpy's seeds
    val_every: int = within(1)
    ckpt_path: str | None
    paths: Paths
    data: Any  # null in eval and visualize until chosen (a checkpoint brings its own)
    model: Model | None
    sampling: Any
    adversarial: Adversarial | None
    trainer: Any
    metrics: Metrics


@dataclass
class TrainConfig(Common):  # conf/train.yaml
    iterations: int = within(1)
    resume: str | None
    checkpoint_every: int = within(0)
    media_every: int = within(0)
    progress_every_s: float | None = within(0)
    compile: Compile


@dataclass
class EvalConfig(Common):  # conf/eval.yaml
    protocol: Protocol | None
    predictions: str | None  # a .npz of predictions from any code (src/scoring.py)
    published: str | None  # PAPER:METHOD or none


@dataclass
class ExportWindowsConfig(Common):  # conf/export_windows.yaml
    protocol: Protocol | None
    out: str | None


@dataclass
class VisualizeConfig(Common):  # conf/visualize.yaml
    action: str
    window: int = within(0)
    baseline: bool
    format: Format
    observed_shown: int = within(1)
    strip_step: int = within(1)


SCHEMAS = {"train": TrainConfig, "eval": EvalConfig, "visualize": VisualizeConfig,
           "export_windows": ExportWindowsConfig}  # fmt: skip

# Trainer keys that the iteration schedule sets or would break (src.train hands iterations and
# val_every to the Trainer as max_steps and val_check_interval): another value would be recorded
# in the run's config.yaml and not be what ran. The values of "not set".
SCHEDULE_OWNS = {"max_steps": -1, "max_epochs": None, "min_steps": None, "min_epochs": None,
                 "val_check_interval": None, "check_val_every_n_epoch": None,
                 "limit_train_batches": None}  # fmt: skip
# Words YAML 1.1 reads as booleans; Hydra reads them as strings, which Python takes as true.
BOOLEAN_WORDS = {"yes", "no", "on", "off"}


class _Builds(BuildsFn):
    """hydra-zen's `builds`, reading `int | None` as Optional[int], and a union without what a
    config cannot hold (`float | Tensor` is a float)."""

    @classmethod
    def _sanitized_type(cls, type_, **kwargs):
        if typing.get_origin(type_) in (Union, types.UnionType):
            plain = (int, float, bool, str, list, dict, tuple, type(None))
            args = [a for a in typing.get_args(type_) if not isinstance(a, type) or a in plain]
            type_ = Union[tuple(args)] if args else Any  # noqa: UP007 (hydra-zen's form)
        return super()._sanitized_type(type_, **kwargs)


@functools.cache
def constructor_schema(target: str, partial: bool = False) -> type:
    """The structured config of the constructor of `target` (through **kwargs, with its base
    class's arguments). `partial`: a node with `_partial_`, whose missing arguments come later."""
    cls = hydra.utils.get_class(target)
    base, params = cls.__base__, inspect.signature(cls).parameters.values()
    inherits = base not in (None, object) and any(p.kind is p.VAR_KEYWORD for p in params)
    bases = (constructor_schema(f"{base.__module__}.{base.__qualname__}"),) if inherits else ()
    return _Builds.builds(
        cls, populate_full_signature=True, zen_partial=partial, builds_bases=bases
    )


def check_types(cfg: DictConfig, entry: str) -> None:
    """A ConfigError naming the first key whose value has the wrong type or range, or that
    nothing reads. `entry`: a key of SCHEMAS."""
    plain, raw = _resolved(cfg), OmegaConf.to_container(cfg, resolve=False)
    _check_node(plain, SCHEMAS[entry], "")
    # Values as written first, copies (${model.net.kernel}) after: named where they were set.
    for copies in (False, True):
        for path, node in _targets(plain, ""):
            try:
                schema = constructor_schema(node["_target_"], "_partial_" in node)
            except Exception as err:  # noqa: BLE001 (ImportError, AttributeError, ...)
                target = node["_target_"]
                raise ConfigError(f"{path}._target_={target} cannot be imported: {err}") from None
            written = functools.reduce(lambda n, k: n.get(k) or {}, path.split("."), raw)
            skip = {"_convert_", "_recursive_", "_args_"} | ({"name"} if path == "data" else set())
            skip |= set() if copies else {k for k, v in written.items() if "${" in str(v)}
            _check_node({k: v for k, v in node.items() if k not in skip}, schema, path)


def _check_node(plain: dict, schema: type, path: str) -> None:
    try:
        typed = OmegaConf.merge(OmegaConf.structured(schema), plain)
    except OmegaConfBaseException as err:
        raise ConfigError(_reworded(err, path)) from None
    _check_as_written(plain, typed, path)
    _check_ranges(plain, schema, path)


def _join(path: str, key: Any) -> str:
    return f"{path}.{key}" if path else str(key)


def _reworded(err: OmegaConfBaseException, path: str) -> str:
    key = _join(path, err.full_key)
    if isinstance(err, ConfigKeyError) and err.parent_node is not None:
        known = [str(k) for k in err.parent_node if not str(k).startswith("_")]
        close = difflib.get_close_matches(str(err.key), known, n=3, cutoff=0.6)
        where = key.rpartition(".")[0]
        hint = f" Did you mean {' or '.join(_join(where, c) for c in close)}?" if close else ""
        target = err.parent_node.get("_target_")
        if target:
            return f"{key} is not an argument of {target}, so it cannot be added.{hint}"
        place = f"under {where}" if where else "at the top level"
        return (
            f"{key}: no such setting {place}, so nothing would read it (a + adds only what the "
            f"code takes).{hint} Settings {place}: {', '.join(sorted(known))}."
        )
    if err.child_node is not None:
        return f"{key}={err.value!r} must be {_words(err.child_node)}."
    kind = err.msg.splitlines()[0].split()[-1]  # "... converted to Integer": a list item
    words = {"Integer": "a whole number", "Float": "a number", "Boolean": "true or false"}
    return f"{key}={err.value!r} must be {words.get(kind, 'of another type')}."


def _words(node: Any) -> str:
    """What a value of `node` is, in words: "a whole number or null", "true or false"."""
    if isinstance(node, AnyNode):  # untyped, and holding a boolean word
        return "true or false"
    if isinstance(node, EnumNode):
        items = [m.name for m in node._metadata.ref_type]
    else:
        items = {BooleanNode: ["true", "false"], IntegerNode: ["a whole number"],
                 FloatNode: ["a number"], StringNode: ["a string"], ListConfig: ["a list"],
                 DictConfig: ["a mapping"]}.get(type(node), ["a value"])  # fmt: skip
    items += ["null"] if node._is_optional() else []
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " or " + items[-1]


def _check_as_written(plain: Any, typed: Any, path: str) -> None:
    """The code reads values as written, not as OmegaConf converts them ('no' to false, 1 to
    true): each must have its type already, and no untyped value may be a YAML boolean word."""
    if isinstance(plain, dict) and isinstance(typed, DictConfig):
        for key, value in plain.items():
            if not (isinstance(value, dict) and "_target_" in value):  # checked on its own
                _check_as_written(value, typed._get_node(key), _join(path, key))
    elif isinstance(plain, list) and isinstance(typed, ListConfig):
        ref = typed._metadata.ref_type  # tuple[int, int] is a list to OmegaConf: its length
        size = typing.get_args(ref) if typing.get_origin(ref) is tuple else (...,)
        if ... not in size and len(size) != len(plain):
            raise ConfigError(f"{path}={plain} must be a list of {len(size)} values.")
        for i, value in enumerate(plain):
            _check_as_written(value, typed._get_node(i), f"{path}[{i}]")
    elif plain is not None and not _as_written(plain, typed):
        raise ConfigError(f"{path}={plain!r} must be {_words(typed)}.")


def _as_written(value: Any, node: Any) -> bool:
    kinds = {BooleanNode: bool, IntegerNode: int, FloatNode: (int, float)}.get(type(node))
    if kinds is not None:  # a bool is an int to Python, not to a config
        return isinstance(value, kinds) and (kinds is bool or not isinstance(value, bool))
    return not (isinstance(node, AnyNode) and str(value).lower() in BOOLEAN_WORDS)


def _check_ranges(plain: dict, schema: type, path: str) -> None:
    for f in dataclasses.fields(schema):
        value, here = plain.get(f.name), _join(path, f.name)
        types_ = (f.type, *getattr(f.type, "__args__", ()))
        inner = [t for t in types_ if dataclasses.is_dataclass(t)]
        if inner and isinstance(value, dict):
            _check_ranges(value, inner[0], here)
        if "range" not in f.metadata or isinstance(value, bool) or value is None:
            continue
        low, high, above = f.metadata["range"]
        if value < low or (above and value == low) or (high is not None and value > high):
            words = f"{'>' if above else '>='} {low}" if high is None else (
                f"in {'(' if above else '['}{low}, {high}]")  # fmt: skip
            raise ConfigError(f"{here}={value} must be {words}.")


def _resolved(node: DictConfig) -> dict:
    """`node` as plain values, resolved, without Hydra's node and the keys that point at state
    not set up yet (the run folder): they are not the user's text."""
    out = {}
    for key in (k for k in node if k != "hydra"):
        with contextlib.suppress(Exception):  # any failure to resolve
            value = node[key]
            if isinstance(value, ListConfig):
                value = OmegaConf.to_container(value, resolve=True)
            out[key] = _resolved(value) if isinstance(value, DictConfig) else value
    return out


def _targets(tree: dict, path: str):
    for key, value in tree.items():
        if isinstance(value, dict):
            here = _join(path, key)
            if isinstance(value.get("_target_"), str):
                yield here, value
            yield from _targets(value, here)


def check(cfg: DictConfig, entry: str, resuming: bool = False) -> None:
    """check_types, then the combinations that cannot work (`resuming` keeps its val_every)."""
    check_types(cfg, entry)
    # A GPU where torch finds none: Lightning would say so in a traceback, after loading data.
    from lightning.pytorch.accelerators import CUDAAccelerator, MPSAccelerator

    accelerator = OmegaConf.select(cfg, "trainer.accelerator", default=None)
    wanted = {"gpu": (CUDAAccelerator, MPSAccelerator), "cuda": (CUDAAccelerator,),
              "mps": (MPSAccelerator,)}.get(accelerator, ())  # fmt: skip
    if wanted and not any(kind.is_available() for kind in wanted):
        build = " (a CPU-only build)" if torch.version.cuda is None else ""
        raise ConfigError(
            f"trainer.accelerator={accelerator} asks for a GPU, and torch {torch.__version__}"
            f"{build} finds none on this machine. Run on the CPU with trainer=cpu, or leave "
            "trainer= out: trainer=default takes a GPU where there is one."
        )
    if entry != "train":
        return
    model = cfg.get("model") or {}
    target = OmegaConf.select(cfg, "model.net._target_", default=None)
    if target and getattr(hydra.utils.get_class(target), "trainable", True) is False:
        raise ConfigError(
            f"{model.name} has no trainable parameters, so there is nothing to train; evaluate "
            f"it with `python -m src.eval model={model.name} data={cfg.data.name}` instead."
        )
    if cfg.compile.enabled not in (True, False, "auto"):
        raise ConfigError(f"compile.enabled={cfg.compile.enabled!r} must be true, false or auto.")
    for key, default in SCHEDULE_OWNS.items():
        value = cfg.trainer.get(key, default)
        if value != default:
            raise ConfigError(
                f"trainer.{key}={value}: the training schedule sets it from iterations="
                f"{cfg.iterations} (the run's length) and val_every={cfg.val_every}; change "
                "those instead."
            )
    check_schedule(cfg, resuming)
    for key in ("model.optimizer.lr", "adversarial.optimizer.lr"):
        # torch accepts lr=0, which trains nothing and says nothing.
        lr = OmegaConf.select(cfg, key, default=None)
        if lr is not None and not lr > 0:
            raise ConfigError(f"{key}={lr} must be > 0 (with 0 nothing is trained).")
    C = OmegaConf.select(cfg, "model.net.C", default=None)
    if C is not None and not 1 <= C <= cfg.data.observed_len:
        raise ConfigError(
            f"model.net.C={C} must be between 1 and data.observed_len={cfg.data.observed_len} "
            "(the short-term window lies inside the observed frames)."
        )


def check_schedule(cfg: DictConfig, resuming: bool = False) -> None:
    """`iterations` must be a multiple of `val_every` (training runs whole validation periods),
    or the run would train another length than asked. A resume keeps its val_every."""
    iterations, every = int(cfg.iterations), int(cfg.val_every)
    if iterations % every == 0:
        return
    lower = iterations // every * every
    lengths = " or ".join(f"iterations={n}" for n in (lower, lower + every) if n > 0)
    divisor = max(d for d in range(1, every + 1) if iterations % d == 0)
    other = " (a resume keeps its run's val_every)" if resuming else f", or val_every={divisor}"
    raise ConfigError(
        f"iterations={iterations} is not a multiple of val_every={every} (training runs whole "
        f"validation periods); use {lengths}{other}."
    )
