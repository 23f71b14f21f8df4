"""What the entry points share on the command line: one-line errors instead of tracebacks,
written `--help` pages, and only the warnings that are true for this project.

A `--help` page is the `hydra.help.template` of the entry point's config (conf/train.yaml):
written text, with `${options:<group>}` where a group's options go, read from conf/<group>/.

`hydra_entry` is the decorator of the Hydra entry points (train, eval, visualize): it checks that
the configs exist (a non-editable install has none), runs Hydra, and prints what Hydra rejects
before the task starts (a misspelt key or option, an unparsable override) as one line naming the
close matches; `friendly_errors` does the same for the project's errors raised by the task.
"""

from __future__ import annotations

import difflib
import functools
import logging
import os
import sys
import warnings
from pathlib import Path

import hydra
from hydra.errors import (
    ConfigCompositionException,
    MissingConfigException,
    OverrideParseException,
    SearchPathException,
)
from omegaconf import DictConfig, OmegaConf

from src.lit.factory import PROJECT_ROOT, ConfigError
from src.lit.run_folders import USER_ERRORS
from src.lit.validation import constructor_args

CONF_DIR = PROJECT_ROOT / "conf"


def group_options(group: str) -> str:
    """The options of a config group, read from conf/<group>/: "cmu, h36m, synthetic". The
    `options` resolver of the entry points' --help pages (`${options:data}` in a config's
    hydra.help.template), so that a page lists what exists."""
    return ", ".join(sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml")))


if not OmegaConf.has_resolver("options"):
    OmegaConf.register_new_resolver("options", group_options)

# What Hydra raises while it composes the config from the command line, before the task runs.
HYDRA_USER_ERRORS = (ConfigCompositionException, OverrideParseException, SearchPathException)


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


class _NoTips(logging.Filter):
    """Lightning's advertisements for its cloud products ("💡 Tip: ... try installing
    litlogger"), printed by every Trainer: nothing a run can act on."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("💡 Tip")


def silence_false_warnings() -> None:
    """Leave out what the libraries print that is false or idle for this project, each message
    by its own text, so that the warnings that remain are true ones."""
    # Lightning 2.6 builds torch's deprecated LeafSpec itself; nothing a user can change.
    leaf_spec = r"`isinstance\(treespec, LeafSpec\)` is deprecated"
    warnings.filterwarnings("ignore", message=leaf_spec, category=FutureWarning)
    tips = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    if not any(isinstance(f, _NoTips) for f in tips.filters):
        tips.addFilter(_NoTips())


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
            silence_false_warnings()
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
        hint = f" Did you mean {' or '.join(f'{group}={c}' for c in close)}?" if close else ""
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
    addable = [a for a in constructor_args(node) if a not in node]
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
