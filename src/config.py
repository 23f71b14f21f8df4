"""The entry points' top-level keys, declared once: dataclasses in Hydra's ConfigStore, the
schema of conf/<entry>.yaml, so Hydra refuses an unknown or wrongly typed key while composing.
A `_target_` node is typed by its constructor's signature (hydra-zen), which checks its ranges;
`check` adds the ranges of the keys no constructor reads and the invariants across keys."""

import dataclasses
import difflib
import functools
import inspect
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Union

import hydra
import torch
from hydra.core.config_store import ConfigStore
from hydra_zen import BuildsFn
from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, OmegaConfBaseException, ValidationError
from omegaconf.nodes import AnyNode, BooleanNode, FloatNode, IntegerNode

from src.data.base import EVAL_PROTOCOLS
from src.metrics.euler_error import DIM_RULES


class ConfigError(ValueError):
    """A configuration value or combination that cannot work."""


def within(low: float, high: float | None = None, *, above: bool = False) -> Any:
    """A key whose value must lie in [low, high] ((low, high] with above=True)."""
    return field(default=MISSING, metadata={"range": (low, high, above)})


def one_of(*names: str | None) -> Any:
    return field(default=MISSING, metadata={"choices": names})


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
# Words YAML 1.1 reads as booleans; Hydra reads them as strings, which Python takes as true.
BOOLEAN_WORDS = {"yes", "no", "on", "off"}


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


def check_types(cfg: DictConfig, entry: str) -> None:
    """A ConfigError naming the first key whose value has the wrong type or range, or that
    nothing reads: the top level, the groups, the constructors' arguments as written."""
    plain, raw = _resolved(cfg), OmegaConf.to_container(cfg, resolve=False)
    _check_node(plain, SCHEMAS[entry], "")  # Hydra checked it, but not a resume's config
    for key, schema in GROUPS.items():
        if isinstance(plain.get(key), dict):
            _check_node(plain[key], schema, key)
    for path, node in _targets(plain, ""):
        try:
            schema = constructor_schema(node["_target_"], "_partial_" in node)
        except Exception as err:  # noqa: BLE001 (ImportError, AttributeError, ...)
            target = node["_target_"]
            raise ConfigError(f"{path}._target_={target} cannot be imported: {err}") from None
        # A copy (${model.net.kernel}) is checked, and named, where it was set.
        written = functools.reduce(lambda n, k: n.get(k) or {}, path.split("."), raw)
        skip = {"_convert_", "_recursive_", "_args_"} | ({"name"} if path == "data" else set())
        skip |= {k for k, v in written.items() if "${" in str(v)}
        _check_node({k: v for k, v in node.items() if k not in skip}, schema, path)


def _check_node(plain: dict, schema: type, path: str) -> None:
    try:
        typed = OmegaConf.merge(OmegaConf.structured(schema), plain)
    except OmegaConfBaseException as err:
        key = _join(path, err.full_key)
        if isinstance(err, ConfigKeyError) and err.parent_node is not None:
            where, target = key.rpartition(".")[0], err.parent_node.get("_target_")
            of = f"an argument of {target}" if target else f"a key of {where or 'the config'}"
            hint = did_you_mean(str(err.key), map(str, err.parent_node), lambda c: _join(where, c))
            raise ConfigError(f"{key} is not {of}, so nothing would read it.{hint}") from None
        raise ConfigError(f"{key}={err.value!r} must be {_words(err.child_node, err)}.") from None
    _check_as_written(plain, typed, path)
    _check_ranges(plain, schema, path)


def did_you_mean(word: str, choices, spell=lambda c: c, cutoff: float = 0.6) -> str:
    """ " Did you mean a or b?" of the choices close to `word`, each as `spell` writes it."""
    close = difflib.get_close_matches(word, [c for c in choices if c[0] != "_"], 3, cutoff)
    return f" Did you mean {' or '.join(map(spell, close))}?" if close else ""


def _join(path: str, key: Any) -> str:
    return f"{path}.{key}" if path else str(key)


def _words(node: Any, err: OmegaConfBaseException | None = None) -> str:
    """What a value of `node` is, in words: "a whole number or null", "true or false"."""
    if node is None:  # a list item: "... could not be converted to Integer"
        kind = err.msg.splitlines()[0].split()[-1] if err else ""
        return {"Integer": "a whole number", "Float": "a number"}.get(kind, "true or false")
    items = {IntegerNode: ["a whole number"], FloatNode: ["a number"], ListConfig: ["a list"],
             DictConfig: ["a mapping"]}.get(type(node), ["true or false"])  # fmt: skip
    return " or ".join(items + (["null"] if node._is_optional() else []))


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
        if dataclasses.is_dataclass(f.type) and isinstance(value, dict):
            _check_ranges(value, f.type, here)
        if "choices" in f.metadata and value not in f.metadata["choices"]:
            words = ", ".join("null" if c is None else c for c in f.metadata["choices"])
            raise ConfigError(f"{here}={value!r} must be one of: {words}.")
        if "range" not in f.metadata or isinstance(value, bool) or value is None:
            continue
        low, high, above = f.metadata["range"]
        if value < low or (above and value == low) or (high is not None and value > high):
            words = f"{'>' if above else '>='} {low}" if high is None else (
                f"in {'(' if above else '['}{low}, {high}]")  # fmt: skip
            raise ConfigError(f"{here}={value} must be {words}.")


def _resolved(node: DictConfig, path: str = "") -> dict:
    """`node` resolved to plain values, without Hydra's node and the keys pointing at the run
    folder (not set up yet); a typed key whose interpolation gives another type is refused."""
    out = {}
    for key in (k for k in node if k != "hydra"):
        try:
            value = node[key]
            if isinstance(value, ListConfig):
                value = OmegaConf.to_container(value, resolve=True)
        except ValidationError as err:
            words = _words(node._get_node(key), err)
            raise ConfigError(f"{_join(path, key)}={err.value!r} must be {words}.") from None
        except Exception:  # noqa: BLE001 (a key that points at the run folder, not set up yet)
            continue
        nested = isinstance(value, DictConfig)
        out[key] = _resolved(value, _join(path, key)) if nested else value
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
