"""What the entry points share on the command line: one-line errors instead of tracebacks,
written `--help` pages, and only the warnings that are true for this project.

`hydra_entry` is the decorator of the Hydra entry points (train, eval, visualize,
export_windows). Every refusal reaches the user through `src.lit.run_folders.refuse`: the
project's errors raised by the task (`friendly_errors`, also used by src.report and
src.plot_errors), those of the run-folder callback, and what Hydra rejects while composing (a
misspelt key or option, an unparsable override), reworded below where Hydra's own text is
several lines without the valid choices. HYDRA_FULL_ERROR=1 shows Hydra's traceback.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import logging
import os
import sys
import warnings

import hydra
from hydra.errors import (
    ConfigCompositionException,
    MissingConfigException,
    OverrideParseException,
    SearchPathException,
)
from omegaconf import DictConfig, OmegaConf

from src.lit.config import constructor_schema
from src.lit.factory import PROJECT_ROOT, ConfigError
from src.lit.run_folders import USER_ERRORS, refuse

CONF_DIR = PROJECT_ROOT / "conf"
# What Hydra raises while it composes the config from the command line, before the task runs.
HYDRA_USER_ERRORS = (ConfigCompositionException, OverrideParseException, SearchPathException)


def group_options(group: str) -> str:
    """The options of a config group, read from conf/<group>/: "cmu, h36m, synthetic" (the
    `options` resolver of the --help pages, so that a page lists what exists)."""
    return ", ".join(sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml")))


if not OmegaConf.has_resolver("options"):
    OmegaConf.register_new_resolver("options", group_options)


def friendly_errors(fn):
    """Print the project's own errors as one message and exit with status 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except USER_ERRORS as err:
            refuse(err)

    return wrapper


def check_installation() -> None:
    """The configs live in conf/ beside the package in the clone; `pip install .` (not
    editable) copies only the package into site-packages, where Hydra then finds no configs."""
    if not (CONF_DIR / "train.yaml").is_file():
        raise ConfigError(
            f"the project's configs are missing: {CONF_DIR} holds no train.yaml, so the package "
            f"was run from {PROJECT_ROOT / 'src'} without the clone it belongs to (as after "
            "`pip install .`, which copies only the Python code). Fix: `pip uninstall "
            "motion-forecast`, then install from the clone with `pip install -e .` (editable) "
            "and run the commands there."
        )


def silence_false_warnings() -> None:
    """Leave out what the libraries print that is false or idle for this project, each message
    by its own text, so that the warnings that remain are true ones."""
    # Lightning 2.6 builds torch's deprecated LeafSpec itself; nothing a user can change.
    leaf_spec = r"`isinstance\(treespec, LeafSpec\)` is deprecated"
    warnings.filterwarnings("ignore", message=leaf_spec, category=FutureWarning)
    # Lightning's advertisements for its cloud products ("💡 Tip: ... try litlogger").
    tips = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    if not any(getattr(f, "__name__", "") == "no_tips" for f in tips.filters):
        tips.addFilter(no_tips)


def no_tips(record: logging.LogRecord) -> bool:
    return not str(record.msg).startswith("💡 Tip")


def hydra_entry(config_name: str):
    """`@hydra.main` for `conf/<config_name>.yaml`, with the project's one-line errors."""

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
                refuse(err)
            if config_name in ("eval", "visualize") and not any(
                a.startswith("data=") for a in sys.argv
            ):  # a checkpoint brings its data config; a partial copy is the machine's fact
                sys.argv = [
                    a.replace("data.allow_partial=", "paths.allow_partial=") for a in sys.argv
                ]
            run = hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name=config_name)
            if os.environ.get("HYDRA_FULL_ERROR") == "1":
                return run(task)()
            os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra raises, instead of printing, its errors
            try:
                return run(task)()
            except HYDRA_USER_ERRORS as err:
                refuse(hydra_error(err, config_name))
            finally:
                os.environ.pop("HYDRA_FULL_ERROR", None)

        return entry

    return decorate


def hydra_error(err: Exception, config_name: str) -> str:
    """One line for an error Hydra raised while composing `config_name`."""
    text, cause = str(err), err.__cause__
    see = f"(`python -m src.{config_name} --help` lists the settings)"
    if isinstance(err, OverrideParseException):
        return (
            f"cannot parse the override {err.override!r}: {err.message.splitlines()[0]}. Fix: "
            "write key=value; quote a value holding '=', ',', spaces or brackets, e.g. "
            "\"ckpt_path='a=b,c/last.ckpt'\"."
        )
    if isinstance(err, MissingConfigException) and err.options is not None:
        group, _, wanted = (err.missing_cfg_file or "?/?").rpartition("/")
        close = difflib.get_close_matches(wanted, err.options, n=3, cutoff=0.5)
        hint = f" Did you mean {' or '.join(f'{group}={c}' for c in close)}?" if close else ""
        return (
            f"{group}={wanted}: no such option of {config_name}.{hint} Choose one of: "
            f"{', '.join(sorted(err.options))}."
        )
    if text.startswith("Could not override '") and getattr(cause, "parent_node", None) is not None:
        return _unknown_key(text.split("'")[1], str(cause.key), cause.parent_node)
    if text.startswith("Could not append to config. An item is already at '"):
        key = text.split("'")[1]
        return f"+{key}: the config already has {key}; set it without the +: {key}=<value> {see}."
    return f"{' '.join(text.split())} {see}"


def _unknown_key(key: str, missing: str, parent: DictConfig) -> str:
    """`key` names `missing`, which `parent` lacks: name the close keys that exist, and the
    constructor arguments of an instantiated node that a + adds."""
    where = parent._get_full_key(None) or ""
    rest = key[len(where) + len(missing) + (1 if where else 0) :]
    if not where and (CONF_DIR / missing).is_dir():  # a group left unchosen (eval's data)
        return (
            f"{key}: no {missing} option is chosen, so there is no {key} to set. Choose one "
            f"before it: {missing}={group_options(missing).replace(', ', '|')} {key}=<value>."
        )
    present = [str(k) for k in parent if not str(k).startswith("_") and k != "hydra"]
    target = parent.get("_target_") if not rest else None
    addable = [a for a in _arguments(target) if a not in parent and a[0] != "_"] if target else []
    if rest:  # the key goes deeper: only a group of settings can match
        present = [k for k in present if isinstance(parent.get(k), DictConfig)]
    close = difflib.get_close_matches(missing, present + addable, n=3, cutoff=0.6)
    spelt = [("+" if c in addable else "") + ".".join(filter(None, (where, c))) + rest
             for c in close]  # fmt: skip
    hint = f" Did you mean {' or '.join(spelt)}?" if close else ""
    keys = ", ".join(sorted(present))
    return f"{key}: no such key.{hint} Keys under {where or 'the top level'}: {keys}."


def _arguments(target: str) -> list[str]:
    try:
        return [f.name for f in dataclasses.fields(constructor_schema(target))]
    except Exception:  # noqa: BLE001 (an unknown target: only the suggestions are lost)
        return []
