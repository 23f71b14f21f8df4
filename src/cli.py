"""What the entry points share (`hydra_entry`): every refusal as one line, exit status 2
(Hydra's own reworded with the close choices; HYDRA_FULL_ERROR=1 shows its traceback), written
`--help` pages, and only the warnings that are true for this project."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import os
import sys
import warnings

import hydra
from hydra.errors import ConfigCompositionException as Composition
from hydra.errors import MissingConfigException, OverrideParseException, SearchPathException
from omegaconf import DictConfig, OmegaConf

from src.config import constructor_schema, did_you_mean
from src.lit.factory import PROJECT_ROOT
from src.lit.run_folders import USER_ERRORS, nothing_left_if_refused, refuse, stop_interrupted

CONF_DIR = PROJECT_ROOT / "conf"
log = logging.getLogger(__name__)
# Lightning's advertisements for its cloud products, and its Ctrl-C line, which ours replaces.
LIGHTNING_NOISE = ("💡 Tip", "Detected KeyboardInterrupt")
no_tips = lambda record: not str(record.msg).lstrip().startswith(LIGHTNING_NOISE)  # noqa: E731


def group_options(group: str) -> str:
    """The options of conf/<group>/, "cmu, h36m, synthetic" (the --help pages' resolver)."""
    return ", ".join(sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml")))


if not OmegaConf.has_resolver("options"):
    OmegaConf.register_new_resolver("options", group_options)


def silence_false_warnings() -> None:
    """Leave out what the libraries print that is false or idle here, each by its own text."""
    # Lightning 2.6 builds torch's deprecated LeafSpec itself; nothing a user can change.
    leaf_spec = r"`isinstance\(treespec, LeafSpec\)` is deprecated"
    warnings.filterwarnings("ignore", message=leaf_spec, category=FutureWarning)
    # A resume continues in its run's checkpoints/; any other run there is refused before.
    warnings.filterwarnings("ignore", message="Checkpoint directory .* exists and is not empty")
    # Lightning's advertisements ("💡 Tip: ... try litlogger") and its Ctrl-C line.
    tips = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    tips.addFilter(no_tips)  # added once however often called


def hydra_entry(config_name: str, started: str | None = None, tidy: bool = True):
    """`@hydra.main` for `conf/<config_name>.yaml`: a refusal is one line (status 2), so is a
    Ctrl-C (130). With `tidy`, either removes what the command put into its run folder, unless
    its file `started` exists (the run had begun)."""

    def decorate(fn):
        @functools.wraps(fn)
        def task(cfg: DictConfig):
            try:
                with nothing_left_if_refused(started) if tidy else contextlib.nullcontext():
                    try:
                        return fn(cfg)
                    except SystemExit as err:  # a Trainer's own exit(1) on Ctrl-C: raised again
                        if not isinstance(err.__context__, KeyboardInterrupt):
                            raise
                        raise err.__context__ from None
            except USER_ERRORS as err:
                # Into the run's log too: its folder stays when the run had begun, and a
                # sweep job's always (train.log said nothing of why the run ended).
                log.error("error: %s", err, extra={"refusal": True})
                refuse(err)
            except KeyboardInterrupt:
                stop_interrupted()

        @functools.wraps(fn)
        def entry(cfg_passthrough: DictConfig | None = None):
            if cfg_passthrough is not None:
                return task(cfg_passthrough)
            silence_false_warnings()
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
            except (Composition, OverrideParseException, SearchPathException) as err:
                refuse(hydra_error(err, config_name))
            except KeyboardInterrupt:  # while Hydra composes, before the task runs
                stop_interrupted()
            finally:
                os.environ.pop("HYDRA_FULL_ERROR", None)

        return entry

    return decorate


def hydra_error(err: Exception, config_name: str) -> str:
    """Hydra's refusal while composing `config_name`, in one line; a misspelt option or key gets
    the close choices (Hydra offers to add the key with +, which nothing would read)."""
    cause = err.__cause__
    if not (CONF_DIR / "train.yaml").is_file():  # `pip install .` copies only the Python code
        return (
            f"the project's configs are missing: {CONF_DIR} holds no train.yaml (as after `pip "
            "install .`, which copies only the Python code). Fix: `pip uninstall motion-forecast`"
            ", then `pip install -e .` (editable) in the clone, and run the commands there."
        )
    if isinstance(err, MissingConfigException) and err.options is not None:
        group, _, wanted = (err.missing_cfg_file or "?/?").rpartition("/")
        return (
            f"{group}={wanted}: no such option of {config_name}."
            f"{did_you_mean(wanted, err.options, lambda c: f'{group}={c}', 0.5)} Choose one of: "
            f"{', '.join(sorted(err.options))}."
        )
    if str(err).startswith("Could not override '") and hasattr(cause, "parent_node"):
        return _unknown_key(str(err).split("'")[1], str(cause.key), cause.parent_node)
    lines = [line.strip() for line in f"{err}\n{cause or ''}".splitlines()]
    text = "; ".join(line for line in lines if line and not line.startswith("object_type"))
    return f"{text} (`python -m src.{config_name} --help` lists the settings)"


def _unknown_key(key: str, missing: str, parent: DictConfig) -> str:
    """`key` names `missing`, which `parent` lacks: the close keys, and arguments a + adds."""
    where = parent._get_full_key(None) or ""
    rest = key[len(where) + len(missing) + bool(where) :]
    group = where or missing
    if (CONF_DIR / group).is_dir() and not (where and len(parent)):  # unchosen (eval's data)
        options = group_options(group).replace(", ", "|")
        return f"{key}: no {group} option is chosen; choose one first: {group}={options} {key}=..."
    present = [str(k) for k in parent if not rest or isinstance(parent[k], DictConfig)]
    addable = []
    with contextlib.suppress(Exception):  # no constructor (or an unknown one): no argument
        fields = dataclasses.fields(constructor_schema(parent["_target_"])) if not rest else ()
        addable = [f.name for f in fields if f.name not in parent]
    spell = lambda c: ("+" if c in addable else "") + ".".join(filter(None, (where, c))) + rest  # noqa: E731
    hint = did_you_mean(missing, present + addable, spell)
    return f"{key}: no such key.{hint} (`--help` lists the settings; --cfg job all keys)"
