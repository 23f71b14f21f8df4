"""The entry points' top-level keys, declared once: dataclasses in Hydra's ConfigStore, the
schema of conf/<entry>.yaml, so Hydra refuses an unknown or wrongly typed key while composing.
A `_target_` node is typed by its constructor's signature (hydra-zen), which checks its ranges;
`check` adds the ranges of the keys no constructor reads and the invariants across keys;
`instantiate` builds a node with a constructor's refusal as one line."""

import dataclasses
import difflib
import functools
import inspect
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

import hydra
import torch
from hydra.core.config_store import ConfigStore
from hydra.errors import InstantiationException
from hydra_zen import BuildsFn
from lightning.fabric.utilities.exceptions import MisconfigurationException
from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, ValidationError
from omegaconf.nodes import AnyNode, BooleanNode, FloatNode, IntegerNode

from src.data.base import EVAL_PROTOCOLS
from src.data.errors import DataError
from src.metrics.euler_error import DIM_RULES

PROJECT_ROOT = Path(__file__).resolve().parents[1]  # conf/ is PROJECT_ROOT / "conf"


class ConfigError(ValueError):
    """A configuration value or combination that cannot work."""


def within(low: float, high: float | None = None, *, above: bool = False) -> Any:
    """A key whose value must lie in [low, high] ((low, high] with above=True), or be null."""
    words = f"{'>' if above else '>='} {low}" if high is None else (
        f"in {'(' if above else '['}{low}, {high}]")  # fmt: skip

    def valid(v: float | None) -> bool:
        return v is None or (v > low if above else v >= low) and (high is None or v <= high)

    return field(default=MISSING, metadata={"valid": (valid, words)})


def one_of(*names: str | None) -> Any:
    words = "one of: " + ", ".join("null" if c is None else c for c in names)
    return field(default=MISSING, metadata={"valid": (lambda v: v in names, words)})


@dataclass
class Paths:
    root_dir: str = MISSING
    archive_dir: str | None = MISSING
    data_dir: str = MISSING
    allow_partial: bool = MISSING  # this machine's data copy lacks files (MOTION_ALLOW_PARTIAL)
    log_dir: str = MISSING
    output_dir: str = MISSING


@dataclass
class Model:  # conf/model/'s keys; src.lit.predictor reads those no constructor reads
    name: str = MISSING
    net: Any = MISSING  # typed by its _target_, as the optimiser
    optimizer: Any = None
    published: Any = None  # src.reporting.published.published_for
    lr_decay_every: int = within(1)
    lr_decay_gamma: float = within(0, 1, above=True)
    lambda_2: float = within(0)
    grad_clip_norm: float | None = within(0, above=True)


@dataclass
class Adversarial:  # conf/adversarial/'s, as Model's
    enabled: bool = MISSING
    lambda_adv: float = within(0)
    lambda_2: float = within(0)
    reference_fake_slot: bool = MISSING
    discriminator: Any = None
    optimizer: Any = None


GROUPS = {"model": Model, "adversarial": Adversarial}  # typed by `check`: their options differ


@dataclass
class Metrics:
    dim_rule: str = one_of(*DIM_RULES)


@dataclass
class Compile:
    enabled: Any = MISSING  # true, false or auto: src.lit.predictor.compiled reads it
    mode: str = MISSING  # torch.compile's


@dataclass
class Common:  # the keys of every entry point's config
    task_name: str = MISSING
    run_name: str = MISSING
    seed: int | None = within(0, 2**32 - 1)  # numpy's seeds
    val_every: int = within(1)
    paths: Paths = MISSING
    data: Any = None  # null in eval and visualize until chosen (a checkpoint brings its own)


@dataclass
class Evaluated(Common):  # ... of those that build a model
    ckpt_path: str | None = MISSING
    model: Any = None
    sampling: Any = None
    adversarial: Any = None
    trainer: Any = MISSING
    metrics: Metrics = MISSING


@dataclass
class TrainConfig(Evaluated):  # conf/train.yaml
    iterations: int = within(1)
    resume: str | None = MISSING
    checkpoint_every: int = within(0)
    media_every: int = within(0)
    progress_every_s: float | None = within(0)
    compile: Compile = MISSING


@dataclass
class EvalConfig(Evaluated):  # conf/eval.yaml
    protocol: str | None = one_of(*EVAL_PROTOCOLS, None)
    predictions: str | None = MISSING  # a .npz of predictions from any code (src/scoring.py)
    published: str | None = MISSING  # PAPER:METHOD or none


@dataclass
class ExportWindowsConfig(Common):  # conf/export_windows.yaml
    protocol: str = one_of(*EVAL_PROTOCOLS)
    out: str | None = MISSING


@dataclass
class VisualizeConfig(Evaluated):  # conf/visualize.yaml
    action: str = MISSING
    window: int = within(0)
    baseline: bool = MISSING
    format: str = one_of("gif", "mp4")
    observed_shown: int = within(1)
    strip_step: int = within(1)


SCHEMAS = {"train": TrainConfig, "eval": EvalConfig, "visualize": VisualizeConfig,
           "export_windows": ExportWindowsConfig}  # fmt: skip
for _name, _schema in SCHEMAS.items():  # conf/<name>.yaml's defaults list starts with it
    ConfigStore.instance().store(name=f"{_name}_schema", node=_schema)

# Trainer keys that the iteration schedule sets (src.train hands iterations and val_every to
# the Trainer as max_steps and val_check_interval): another value would be recorded in the
# run's config.yaml and not be what ran. The values of "not set".
SCHEDULE_OWNS = {"max_steps": -1, "max_epochs": None, "min_steps": None, "min_epochs": None,
                 "val_check_interval": None, "check_val_every_n_epoch": None,
                 "limit_train_batches": None}  # fmt: skip


class _Builds(BuildsFn):
    """hydra-zen's `builds`; `int | None` is Optional[int], `float | Tensor` a float."""

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


def instantiate(node, **kwargs):
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


def check_types(cfg: DictConfig, entry: str) -> None:
    """A ConfigError naming the first key whose value has the wrong type or range, or that
    nothing reads, in one merge: the top level (Hydra checked it, but not a resume's config),
    model and adversarial, and each `_target_`'s arguments as its constructor types them."""
    plain, raw = _resolved(cfg), OmegaConf.to_container(cfg, resolve=False)
    schema = OmegaConf.structured(SCHEMAS[entry])
    for key, group in GROUPS.items():
        if isinstance(plain.get(key), dict):
            schema[key] = OmegaConf.structured(group)
    for path, node in list(_targets(plain, "")):
        try:
            typed = OmegaConf.structured(constructor_schema(node["_target_"], "_partial_" in node))
        except Exception as err:  # noqa: BLE001 (ImportError, AttributeError, ...)
            target = node["_target_"]
            raise ConfigError(f"{path}._target_={target} cannot be imported: {err}") from None
        OmegaConf.update(schema, path, typed, merge=False)
        # A copy (${model.net.kernel}) is checked, and named, where it was set.
        written = functools.reduce(lambda n, k: n.get(k) or {}, path.split("."), raw)
        unread = {"_convert_", "_recursive_", "_args_"} | ({"name"} if path == "data" else set())
        for key in [k for k in node if k in unread or "${" in str(written.get(k))]:
            del node[key]
    try:
        typed = OmegaConf.merge(schema, plain)
    except ConfigKeyError as err:
        where, target = err.full_key.rpartition(".")[0], err.parent_node.get("_target_")
        of = f"an argument of {target}" if target else f"a key of {where or 'the config'}"
        hint = did_you_mean(str(err.key), map(str, err.parent_node), lambda c: _join(where, c))
        raise ConfigError(f"{err.full_key} is not {of}, so nothing would read it.{hint}") from None
    except ValidationError as err:
        raise ConfigError(f"{err.full_key}={err.value!r} must be {_words(err)}.") from None
    _check_as_written(plain, typed, "")
    _check_ranges(plain, typed, "")


def did_you_mean(word: str, choices, spell=lambda c: c, cutoff: float = 0.6) -> str:
    """ " Did you mean a or b?" of the choices close to `word`, each as `spell` writes it."""
    close = difflib.get_close_matches(word, [c for c in choices if c[0] != "_"], 3, cutoff)
    return f" Did you mean {' or '.join(map(spell, close))}?" if close else ""


def _join(path: str, key: Any) -> str:
    return f"{path}.{key}" if path else str(key)


WORDS = {BooleanNode: "true or false", IntegerNode: "a whole number", FloatNode: "a number",
         ListConfig: "a list", DictConfig: "a mapping", int: "a whole number",
         float: "a number"}  # fmt: skip


def _words(where: Any) -> str:
    """What a value of a node (or of the node a ValidationError names) is, in words: "a whole
    number or null"; an untyped node's, where a boolean word was written, "true or false"."""
    node = where.child_node if isinstance(where, ValidationError) else where
    if node is None:  # an item of a typed list
        return WORDS.get(where.parent_node._metadata.element_type, "true or false")
    return WORDS.get(type(node), "true or false") + (" or null" if node._is_optional() else "")


# Words YAML 1.1 reads as booleans; Hydra reads them as strings, which Python takes as true.
BOOLEAN_WORDS = {"yes", "no", "on", "off"}


def _check_as_written(plain: Any, typed: Any, path: str) -> None:
    """The code reads values as written, not as OmegaConf converts them ('no' to false, 1 to
    true): each must have its type already, and no untyped value may be a YAML boolean word."""
    if isinstance(plain, dict) and isinstance(typed, DictConfig):
        for key, value in plain.items():
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


def _check_ranges(plain: dict, typed: DictConfig, path: str) -> None:
    """The ranges and choices of the keys of src/config.py's dataclasses (`within`, `one_of`)."""
    for key, value in plain.items():
        if isinstance(value, dict):
            _check_ranges(value, typed._get_node(key), _join(path, key))
    kind = OmegaConf.get_type(typed)
    for f in dataclasses.fields(kind) if dataclasses.is_dataclass(kind) else ():
        value, (valid, words) = plain.get(f.name), f.metadata.get("valid", (None, ""))
        if valid is not None and not valid(value):
            raise ConfigError(f"{_join(path, f.name)}={value!r} must be {words}.")


def _resolved(node: DictConfig) -> dict:
    """`node` resolved to plain values, without Hydra's node and the keys pointing at the run
    folder (not set up yet); a typed key whose interpolation gives another type is refused."""
    out = {}
    for key in (k for k in node if k != "hydra"):
        try:
            value = node[key]
            if isinstance(value, ListConfig):
                value = OmegaConf.to_container(value, resolve=True)
        except ValidationError as err:
            raise ConfigError(f"{err.full_key}={err.value!r} must be {_words(err)}.") from None
        except Exception:  # noqa: BLE001 (the run folder, or a key its config leaves unset)
            continue
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
    """check_types, then the invariants across keys (`resuming` keeps its val_every)."""
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
    for key, default in SCHEDULE_OWNS.items():
        value = cfg.trainer.get(key, default)
        if value != default:
            raise ConfigError(
                f"trainer.{key}={value}: the training schedule sets it from iterations="
                f"{cfg.iterations} (the run's length) and val_every={cfg.val_every}; change "
                "those instead."
            )
    check_schedule(cfg, resuming)


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
