"""What the entry points share (`hydra_entry`): every refusal as one line, exit status 2
(Hydra's own reworded with the close choices; HYDRA_FULL_ERROR=1 shows its traceback), written
`--help` pages, and only the warnings that are true for this project. And run folders: every
run gets a new one (`<time>`, `<time>-1`, ...); one named with `hydra.run.dir=...` is refused
when it holds a run. A refused config creates no folder (src.prepare.PrepareRun checks it
first); what is found later (a misspelt action) removes the folder made for it
(`nothing_left_if_refused`)."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path
from typing import NoReturn

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import ConfigCompositionException as Composition
from hydra.errors import MissingConfigException, OverrideParseException, SearchPathException
from omegaconf import DictConfig, OmegaConf

from src.config import PROJECT_ROOT, ConfigError, constructor_schema, did_you_mean
from src.data.errors import DataError
from src.data.files import claim_folder
from src.lit.checkpoints import CheckpointError
from src.lit.predictor import NonFiniteLossError

CONF_DIR = PROJECT_ROOT / "conf"
log = logging.getLogger(__name__)
# Lightning's advertisements for its cloud products, and its Ctrl-C line, which ours replaces.
LIGHTNING_NOISE = ("💡 Tip", "Detected KeyboardInterrupt")
no_tips = lambda record: not str(record.msg).lstrip().startswith(LIGHTNING_NOISE)  # noqa: E731


def group_options(group: str) -> str:
    """The options of conf/<group>/, "cmu, h36m, synthetic" (the --help pages' resolver)."""
    return ", ".join(sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml")))


# A user's mistake (bad data, config, checkpoint, a diverged run): printed as one line.
USER_ERRORS = (DataError, ConfigError, CheckpointError, NonFiniteLossError)


def refuse(err: object) -> NoReturn:
    """What a user sees instead of a traceback: `error: <what is wrong and the fix>`, status 2."""
    print(f"error: {err}", file=sys.stderr)
    sys.exit(2)


def stop_interrupted() -> NoReturn:
    """What Ctrl-C ends a command with instead of a traceback: one line saying what became of
    its run folder (nothing_left_if_refused tidied it unless the run had started), status 130
    (128 + SIGINT, as a shell reports a Ctrl-C)."""
    where = ""
    if HydraConfig.initialized():
        folder = Path(HydraConfig.get().runtime.output_dir)
        if not folder.exists():
            where = f"; its unfinished run folder {folder} was removed"
        elif _claimed.get("tidied"):  # a folder named with hydra.run.dir, holding files before
            where = f"; what it had written into {folder} was removed, the rest left as it was"
        else:
            where = f"; the run folder {folder} is kept"
    print(f"interrupted (Ctrl-C){where}", file=sys.stderr)
    sys.exit(130)


class PrintedByRefuse(logging.Filter):
    """For the console handler (conf/hydra/default.yaml): a refusal logged for the run's
    train.log (`extra={"refusal": True}`) is on the console already, printed by `refuse`."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not getattr(record, "refusal", False)


def path_safe(text: str) -> str:
    """`text` with `_` for what stops Hydra's parser or a shell: a folder works in `ckpt_path=`."""
    return re.sub(r"[^A-Za-z0-9_.+@-]", "_", str(text))


def training_run_name(ckpt_path: str | Path) -> str:
    """`run_name` of the config.yaml of a checkpoint's run (<run>/checkpoints/<file>.ckpt),
    else the run folder's name (its parent's when the folder is a timestamp)."""
    path = Path(ckpt_path)
    run = path.parent.parent if path.parent.name == "checkpoints" else path.parent
    with contextlib.suppress(Exception):  # an unreadable config only loses the name
        name = OmegaConf.load(run / "config.yaml").get("run_name")
        if isinstance(name, str) and name:
            return name
    stamp = run.name.replace("-", "").replace("_", "")
    return run.parent.name if stamp.isdigit() else run.name


def evaluated_name(
    ckpt_path: str | None, model: str | None, data: str | None, predictions: str | None = None
) -> str:
    """The run_name of an evaluation (conf/eval.yaml): <training run>_<checkpoint file>,
    <model>_<data> for a baseline, predictions_<file stem>_<data> for a file of predictions."""
    if ckpt_path:
        return f"{training_run_name(ckpt_path)}_{Path(str(ckpt_path)).stem}"
    if predictions:
        return f"predictions_{Path(str(predictions)).stem}_{data or 'data'}"
    return f"{model or 'checkpoint'}_{data or 'data'}"


def register_resolvers() -> None:
    """The resolvers conf/ uses (registered on import, too)."""
    for name, resolver in (("project_root", lambda: str(PROJECT_ROOT)), ("options", group_options),
                           ("evaluated", evaluated_name), ("path_safe", path_safe)):  # fmt: skip
        OmegaConf.register_new_resolver(name, resolver, replace=True)


register_resolvers()


def holds_run(folder: Path) -> bool:
    return (folder / "config.yaml").exists() or any(folder.glob("checkpoints/*.ckpt"))


_claimed: dict = {}  # this process's folder, what it held before, the folders made for it


def claim_run_folder(folder: str | os.PathLike, exact: bool = False) -> Path:
    """Create this run's folder, which no other process can get. exact=True: the user named
    it; an existing one is used only if it holds no run (the .hydra/ made here is the claim)."""
    folder = Path(folder)
    made = [p for p in folder.parents if not p.exists()]
    if not exact:
        folder = claim_folder(folder)
        _claimed.update(folder=folder, before=set(), made=[folder, *made])
        return folder
    made = made if folder.exists() else [folder, *made]
    folder.mkdir(parents=True, exist_ok=True)
    before = set(os.listdir(folder))
    try:
        (folder / ".hydra").mkdir()  # one process alone can create it
        if holds_run(folder):
            (folder / ".hydra").rmdir()
            raise FileExistsError
    except FileExistsError:
        raise ConfigError(
            f"the run folder {folder} (hydra.run.dir) already holds a run; nothing was "
            "written to it. Name another folder, or leave hydra.run.dir out to get a new "
            "timestamped one."
        ) from None
    _claimed.update(folder=folder, before=before, made=made)
    return folder


@contextlib.contextmanager
def nothing_left_if_refused(started: str | None = "config.yaml"):
    """A user error or a Ctrl-C raised inside removes what this process put into the run
    folder, unless the run had started (its file `started` exists; None: never), and goes on:
    a folder is complete or gone, never half-written."""
    try:
        yield
    except (*USER_ERRORS, KeyboardInterrupt):
        folder = Path(HydraConfig.get().runtime.output_dir)
        claimed = _claimed.get("folder")
        mine = claimed is not None and claimed.resolve() == folder.resolve()
        if not mine or (started and (folder / started).exists()):
            raise
        _claimed["tidied"] = True
        for name in set(os.listdir(folder)) - _claimed["before"]:
            path = folder / name
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
        for made in _claimed["made"]:
            with contextlib.suppress(OSError):  # only if empty: another run may use a parent
                made.rmdir()
        raise


def git_commit() -> str:
    """The short commit hash, "-dirty" with uncommitted changes to tracked files."""
    cmd = ["git", "describe", "--always", "--dirty", "--exclude=*"]  # no tag names
    try:
        run = subprocess.run(cmd, cwd=PROJECT_ROOT, capture_output=True, text=True, check=True)
        return run.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


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
