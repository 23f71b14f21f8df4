"""What the user typed is what runs (issue #26): a misspelt option of any config group and a
value of the wrong type are refused before anything runs, never replaced by a default; and the
rows of the issue's table, one section each."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from src.config import ConfigError
from tests.conftest import CONF, refused, run_module


def _groups() -> list[str]:
    """Every config group under conf/ (hydra/launcher included), read from the folders."""
    return sorted(
        str(folder.relative_to(CONF))
        for folder in CONF.rglob("*")
        if folder.is_dir() and list(folder.glob("*.yaml"))
    )


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


def _refusal(config_name: str, argv: list[str], monkeypatch, capsys) -> str:
    """The one error line of `python -m src.<config_name> argv...`, in-process, through the
    entry points' decorator; the task must not run."""
    from src.cli import hydra_entry

    called = []
    monkeypatch.setattr(sys, "argv", [f"src.{config_name}", *argv])
    with pytest.raises(SystemExit) as info:
        hydra_entry(config_name)(lambda cfg: called.append(cfg))()
    assert info.value.code == 2 and not called
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: "), err
    return err.strip()


# ------------------------------------------------ rows 1-2: a misspelt option of any group
def _misspelt(options: list[str]) -> str:
    """An option one letter off the first one, which is no option itself."""
    wrong = options[0][:-1]
    return wrong if wrong and wrong not in options else options[0] + "x"


GROUPS_OF = {
    "train": _groups(),
    # eval and visualize compose the groups of their defaults lists (and Hydra's own).
    "eval": [g for g in _groups() if g.split("/")[0] in
             ("paths", "data", "sampling", "adversarial", "model", "trainer", "hydra")],
}  # fmt: skip
GROUPS_OF["visualize"] = GROUPS_OF["eval"]


@pytest.mark.parametrize(
    ("config_name", "group"),
    [(config, group) for config, groups in GROUPS_OF.items() for group in groups],
)
def test_a_misspelt_option_of_every_group_is_refused_naming_the_options(
    config_name, group, tmp_path, monkeypatch, capsys
):
    """Before, the `optional` groups of conf/train.yaml (experiment, reproduce, debug,
    hparams_search) ignored an option that does not exist: `debug=fast` trained 20,000
    iterations of the defaults."""
    options = _options(group)
    wrong = _misspelt(options)
    err = _refusal(config_name, [f"{group}={wrong}", f"paths.log_dir={tmp_path}"], monkeypatch,
                   capsys)  # fmt: skip
    refused(err, f"{group}={wrong}", ", ".join(options))
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        # row 1: one word off; it used to train the default conv_s2s on H3.6M
        (["experiment=martinez2017_residual_sup"],
         ["experiment=martinez2017_residual_sup", "experiment=martinez2017_res_sup"]),
        # row 2: a 20,000-iteration run (ETA 7 h) instead of a debug run; one default run
        # instead of a sweep
        (["debug=fast", "data=synthetic"], ["debug=fast", "debug=fast_dev_run"]),
        (["-m", "reproduce=paper"], ["reproduce=paper", "reproduce=papers"]),
        (["-m", "hparams_search=optuna"], ["hparams_search=optuna", "=conv_s2s_optuna"]),
    ],
)  # fmt: skip
def test_rows_1_2_misspelt_experiment_debug_and_sweeps_are_refused(
    argv, expected, tmp_path, monkeypatch, capsys
):
    err = _refusal("train", [*argv, f"paths.log_dir={tmp_path}"], monkeypatch, capsys)
    refused(err, *expected)
    assert not list(tmp_path.iterdir())  # no run folder, no sweep folder


def test_optional_groups_left_unset_still_compose(tmp_path):
    from tests.conftest import compose_config

    cfg = compose_config("train", [], tmp_path)
    choices = cfg.hydra.runtime.choices
    assert [choices[g] for g in ("experiment", "reproduce", "debug", "hparams_search")] == [
        None
    ] * 4
    assert cfg.model.name == "conv_s2s" and cfg.iterations == 20000


# ------------------------------------------- rows 3-4: values checked against their types
def _leaves(node: dict, path: str = ""):
    for key, value in node.items():
        here = f"{path}.{key}" if path else str(key)
        if isinstance(value, dict):
            yield from _leaves(value, here)
        else:
            yield here, value


# The default config, and each option that brings boolean keys of its own.
BOOLEAN_CONFIGS = [
    ("train", []),
    ("train", ["model=gru_s2s"]),
    ("train", ["trainer=ddp"]),
    ("eval", ["model=zero_velocity", "data=h36m"]),
    ("visualize", ["model=zero_velocity", "data=h36m"]),
]


def _boolean_keys() -> list[tuple[str, list[str], str]]:
    from omegaconf import OmegaConf

    from tests.conftest import compose_config

    found = {}
    for config_name, base in BOOLEAN_CONFIGS:
        cfg = compose_config(config_name, base, "/nonexistent")
        plain = OmegaConf.to_container(cfg, resolve=False)
        del plain["hydra"]  # Hydra's own config (--cfg job leaves it out too)
        for key, value in _leaves(plain):
            if isinstance(value, bool):
                found.setdefault((config_name, key), base)
    return [(config_name, base, key) for (config_name, key), base in found.items()]


# and the booleans written as interpolations: the machine's fact, and the data's copy of it
BOOLEAN_KEYS = _boolean_keys() + [
    ("train", [], k) for k in ("paths.allow_partial", "data.allow_partial")
]


def test_the_boolean_keys_cover_what_the_issue_names():
    keys = {key for _, _, key in BOOLEAN_KEYS}
    assert {"model.net.long_term", "data.allow_partial", "adversarial.enabled",
            "trainer.deterministic", "model.net.tied", "baseline"} <= keys  # fmt: skip
    assert len(keys) >= 15


@pytest.mark.parametrize(("config_name", "base", "key"), BOOLEAN_KEYS)
def test_every_boolean_key_set_to_no_is_refused_or_false_never_true(
    config_name, base, key, tmp_path
):
    """Hydra reads `key=no` as the string 'no', which Python takes as true: the long-term
    encoder stayed (row 3), data.allow_partial=no trained on a partial copy (row 4)."""
    from omegaconf import OmegaConf

    from src.config import check
    from src.prepare import prepare_training
    from tests.conftest import compose_config

    cfg = compose_config(config_name, [*base, f"{key}=no"], tmp_path)
    try:
        if config_name == "train":
            prepare_training(cfg, [], {})
        else:
            check(cfg, config_name)
    except ConfigError as err:
        refused(str(err), f"{key}='no'", "true or false")
        return
    assert OmegaConf.select(cfg, key) is False


@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        # row 3: the ablation ran the full model (5.8 M parameters, as with true)
        (["model.net.long_term=no"], ["model.net.long_term='no'", "true or false"]),
        # row 4: logged allow_partial=true and trained
        (["data=cmu", "data.allow_partial=no"], ["data.allow_partial='no'", "true or false"]),
        (["data.allow_partial=yes"], ["data.allow_partial='yes'", "true or false"]),
        # a boolean word where the type is a union (true, false or "warn")
        (["trainer.deterministic=off"], ["trainer.deterministic='off'", "true or false"]),
        (["model.net.kernel=[2,x]"], ["model.net.kernel[1]='x'", "a whole number"]),
        (["model.net.kernel=[2]"], ["model.net.kernel=[2]", "a list of 2 values"]),
        (["model.net.dropout=0.5"], ["model.net.dropout=0.5", "a list"]),
        (["model.lr_decay_every=1e4"], ["model.lr_decay_every=10000.0", "a whole number"]),
        (["adversarial.enabled=1"], ["adversarial.enabled=1", "true or false"]),
        (["sampling=linear", "sampling.steps=abc"], ["sampling.steps='abc'", "a whole number"]),
        (["+model.net.d_dec=1.5"], ["model.net.d_dec=1.5", "a whole number"]),
        (["model.optimizer._partial_=no"], ["model.optimizer._partial_='no'", "true or false"]),
        # a key added with + that nothing reads (Hydra adds it without a word)
        (["+iteratons=100"], ["iteratons", "iterations?"]),
        (["+model.lr_decay=3"], ["model.lr_decay", "model.lr_decay_every"]),
    ],
)  # fmt: skip
def test_rows_3_4_values_of_the_wrong_type_are_refused_naming_the_type(overrides, named, train_cfg):
    from src.prepare import prepare_training

    with pytest.raises(ConfigError) as err:
        prepare_training(train_cfg(*overrides), [], {})
    refused(str(err.value), *named)


def test_row_3_long_term_false_builds_the_ablation(train_cfg, synthetic_data_dir):
    from src.build import build_datamodule, build_module
    from src.prepare import prepare_training

    sizes = {}
    for value in ("true", "false"):
        cfg = train_cfg(f"model.net.long_term={value}", "adversarial=none")
        prepare_training(cfg, [], {})
        dm = build_datamodule(cfg.data)
        dm.prepare_data()
        dm.setup("fit")
        sizes[value] = sum(p.numel() for p in build_module(cfg, dm).net.parameters())
    assert sizes["false"] < sizes["true"] / 2  # 2.0 M against 5.8 M on H3.6M


def test_every_key_of_every_shipped_config_has_a_declared_type(tmp_path):
    """One declaration per key (src/config.py, or the constructor a node instantiates): a
    key added to a config without a type is caught here, not by a user."""
    from src.config import check_types
    from tests.conftest import compose_config

    compositions = [("train", [f"{group}={option}"]) for group in _groups()
                    if not group.startswith("hydra") for option in _options(group)]  # fmt: skip
    compositions += [(name, ["model=zero_velocity", "data=cmu"]) for name in ("eval", "visualize")]
    compositions += [(name, ["ckpt_path=a.ckpt"]) for name in ("eval", "visualize")]
    compositions += [("eval", ["predictions=p.npz", "data=h36m"])]
    compositions += [("export_windows", [f"data={d}", "out=w.npz"]) for d in ("h36m", "cmu")]
    for config_name, overrides in compositions:
        cfg = compose_config(config_name, overrides, tmp_path)
        check_types(cfg, config_name)


# ---------------------------------------------------- row 5: a GPU where there is none
def test_row_5_a_gpu_asked_for_where_there_is_none_is_one_line(train_cfg, monkeypatch):
    from lightning.pytorch.accelerators import CUDAAccelerator, MPSAccelerator

    from src.prepare import prepare_training

    for kind in (CUDAAccelerator, MPSAccelerator):  # this machine, whatever it has
        monkeypatch.setattr(kind, "is_available", staticmethod(lambda: False))
    for overrides in (["trainer=gpu"], ["trainer.accelerator=cuda"]):
        with pytest.raises(ConfigError) as err:
            prepare_training(train_cfg(*overrides), [], {})
        refused(str(err.value), "trainer.accelerator=", "trainer=cpu")
        assert "\n" not in str(err.value)


@pytest.mark.skipif(
    __import__("torch").cuda.is_available(), reason="this machine has a GPU: trainer=gpu works"
)
def test_row_5_cli_trainer_gpu_without_a_gpu_is_one_line(tmp_path, synthetic_data_dir):
    """It used to be a 79-line traceback ending in "No supported gpu backend found!"."""
    proc = run_module("src.train", "trainer=gpu", "data=synthetic", data_dir=synthetic_data_dir,
                      log_dir=tmp_path)  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    (line,) = [x for x in proc.stderr.splitlines() if x.startswith("error: ")]
    assert line.startswith("error: trainer.accelerator=gpu asks for a GPU")
    assert "trainer=cpu" in line
    assert not tmp_path.exists() or not list(tmp_path.rglob("*"))


def test_row_5_a_trainer_setting_lightning_refuses_is_a_config_error(train_cfg):
    from src.config import instantiate

    with pytest.raises(ConfigError, match=r"Trainer: `Trainer\(devices=0\)` value is not a valid"):
        instantiate(train_cfg("trainer.devices=0").trainer)


# ---------------------------------------------------- rows 6 and 8: resumes
def _fake_run(folder: Path, data_dir: Path, *overrides: str) -> Path:
    """A run folder as training leaves it (config.yaml, checkpoints/last.ckpt), without
    training: the resume logic reads only these files."""
    from omegaconf import OmegaConf

    from tests.conftest import compose_config

    cfg = compose_config("train", list(overrides), folder, data_dir)
    task = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])
    folder.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(task, folder / "config.yaml", resolve=True)
    (folder / "checkpoints").mkdir()
    (folder / "checkpoints" / "last.ckpt").write_bytes(b"")
    return folder


RUN = ["data=synthetic", "model=gru_s2s", "model.net.hidden=16", "iterations=6", "val_every=2"]


@pytest.mark.parametrize("layout", ["runs/gru_s2s_synthetic/2026-01-01_00-00-00",
                                    "multiruns/2026-01-01_00-00-00/0_model-gru_s2s"])  # fmt: skip
def test_row_6_a_resumed_run_goes_under_the_outputs_folder_of_its_run(
    layout, tmp_path, synthetic_data_dir
):
    """A run started with paths.log_dir=/elsewhere used to resume into ./outputs/..."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from src.prepare import restore_run
    from tests.conftest import compose_config

    elsewhere = tmp_path / "elsewhere"
    run = _fake_run(elsewhere / "train" / layout, synthetic_data_dir, *RUN)
    cfg = compose_config("train", [f"resume={run}"], tmp_path / "here", synthetic_data_dir)
    choices = OmegaConf.to_container(HydraConfig.get().runtime.choices)
    # The command line as typed: no paths.log_dir (compose_config adds one of its own).
    restored, _ = restore_run(cfg, [f"resume={run}"], choices)
    assert restored.paths.log_dir == str(elsewhere)
    run_dir = OmegaConf.to_container(cfg.hydra.run, resolve=False)["dir"]
    assert run_dir.startswith("${paths.log_dir}/${task_name}/runs/${run_name}/")  # so, beside it
    # A log_dir given on the command line is still the user's choice.
    restored, _ = restore_run(cfg, [f"resume={run}", f"paths.log_dir={tmp_path / 'here'}"],
                              choices)  # fmt: skip
    assert restored.paths.log_dir == str(tmp_path / "here")


def test_row_8_a_refused_resume_says_which_keys_may_change(tmp_path, synthetic_data_dir):
    """+trainer.precision=bf16-mixed was refused with a message saying trainer keys may change."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from src.lit.checkpoints import CheckpointError
    from src.prepare import restore_run
    from tests.conftest import compose_config

    run = _fake_run(tmp_path / "run", synthetic_data_dir, *RUN)
    overrides = [f"resume={run}", "+trainer.precision=bf16-mixed"]
    cfg = compose_config("train", overrides, tmp_path / "new", synthetic_data_dir)
    choices = OmegaConf.to_container(HydraConfig.get().runtime.choices)
    with pytest.raises(CheckpointError) as err:
        restore_run(cfg, overrides, choices)
    message = str(err.value)
    assert "trainer.precision: checkpoint absent, command line bf16-mixed" in message
    allowed = message.split("only these may differ: ")[1]
    assert "trainer.* except trainer.precision" in allowed and "iterations" in allowed
    assert "trainer keys may change" not in message


# ------------------------------------- rows 7 and 11: what a run prints (6: where it resumes)
FALSE_WARNINGS = (
    "dataloader is not resumable",  # the training sampler resumes exactly
    "dirpath has changed",  # a resume in its run's folder restores the best as it was
    "exists and is not empty",  # a resume continues in its run's checkpoints/
    "weights_only",  # Lightning's note when the argument is left to its default
    "LeafSpec",  # a deprecation inside Lightning
    "litlogger",  # an advertisement
    "Tip:",
)

DIE_AFTER_SAVE = """
import os

from src.lit.checkpoints import LastCheckpoint

_save = LastCheckpoint.save


def _save_then_die(self, trainer, pl_module):
    _save(self, trainer, pl_module)
    if pl_module.global_step == int(os.environ["DIE_AFTER"]):
        os._exit(137)


LastCheckpoint.save = _save_then_die
"""


def _printed(proc) -> str:
    return proc.stdout + proc.stderr


def test_row_7_evaluation_prints_no_false_warnings(tmp_path, synthetic_data_dir):
    proc = run_module("src.eval", "model=zero_velocity", "data=synthetic", "trainer=cpu",
                      data_dir=synthetic_data_dir, log_dir=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    for text in FALSE_WARNINGS:
        assert text not in _printed(proc), text


def test_row_7_only_the_false_warnings_are_silenced():
    import logging
    import warnings

    from lightning.pytorch.utilities.rank_zero import rank_zero_warn

    from src.cli import silence_false_warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        silence_false_warnings()  # after simplefilter: its filters come first
        rank_zero_warn("a real warning: the data has only 3 windows")
        warnings.warn("`isinstance(treespec, LeafSpec)` is deprecated", FutureWarning, stacklevel=1)
    assert [str(w.message) for w in caught] == ["a real warning: the data has only 3 windows"]
    tips = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    assert not tips.filter(logging.makeLogRecord({"msg": "💡 Tip: try installing litlogger"}))
    assert tips.filter(logging.makeLogRecord({"msg": "GPU available: False, used: False"}))


@pytest.mark.slow
def test_rows_6_7_11_a_killed_and_resumed_run_prints_the_truth(tmp_path, synthetic_data_dir):
    """A run killed mid-epoch (right after last.ckpt at iteration 1), then resumed by its
    folder alone: no false warning in either, the run continued in its own folder although the
    resume names no paths.log_dir, and the best checkpoint printed at the end."""
    import os
    import subprocess

    from tests.conftest import ROOT

    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(DIE_AFTER_SAVE)
    env = {**os.environ, "MOTION_DATA_DIR": str(synthetic_data_dir), "OMP_NUM_THREADS": "1"}
    elsewhere = tmp_path / "elsewhere"
    gru = [*RUN[:3], "trainer=cpu", "trainer.enable_progress_bar=false", "media_every=0",
           "iterations=4", "val_every=2"]  # fmt: skip

    def train(*args: str, **extra: str):
        cmd = [sys.executable, "-m", "src.train", *args]
        return subprocess.run(
            cmd, cwd=ROOT, env={**env, **extra}, capture_output=True, text=True, timeout=600
        )

    path = os.pathsep.join([str(hook), str(ROOT)])
    killed = train(*gru, "checkpoint_every=1", f"paths.log_dir={elsewhere}",
                   PYTHONPATH=path, DIE_AFTER="1")  # fmt: skip
    assert killed.returncode == 137, killed.stderr[-3000:]
    (run,) = (elsewhere / "train" / "runs").glob("*/*")
    resumed = train(f"resume={run}")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    for proc in (killed, resumed):
        for text in FALSE_WARNINGS:
            assert text not in _printed(proc), (text, _printed(proc)[-3000:])
    # Row 6: in the run's own folder, not under ./outputs.
    assert list((elsewhere / "train" / "runs").glob("*/*")) == [run]
    new = run
    (best,) = [x for x in resumed.stdout.splitlines() if "best checkpoint: " in x]
    best = Path(best.split("best checkpoint: ", 1)[1])
    assert best.is_file() and best.parent == new / "checkpoints"  # row 11


# ------------------------------------------ row 9: output folders name what they evaluate
@pytest.mark.parametrize("config_name", ["eval", "visualize"])
def test_row_9_folders_of_different_checkpoints_tell_them_apart(
    config_name, tmp_path, synthetic_data_dir
):
    """Every checkpoint's output used to land in .../checkpoint_data/<time>."""
    from tests.conftest import compose_config

    li = _fake_run(tmp_path / "train/runs/li/2026-01-01_00-00-00", synthetic_data_dir, *RUN,
                   "run_name=li2018_h36m")  # fmt: skip
    gru = _fake_run(tmp_path / "train/runs/gru/2026-01-01_00-00-00", synthetic_data_dir, *RUN)
    folders = {}
    for ckpt in (li / "checkpoints" / "last.ckpt", gru / "checkpoints" / "best-epoch002.ckpt"):
        cfg = compose_config(config_name, [f"ckpt_path={ckpt}"], tmp_path / "out")
        folders[ckpt] = Path(str(cfg.hydra.run.dir)).parent.name
    suffix = "_walking" if config_name == "visualize" else ""
    assert list(folders.values()) == [
        f"li2018_h36m_last{suffix}",
        f"gru_s2s_synthetic_best-epoch002{suffix}",
    ]
    baseline = compose_config(config_name, ["model=zero_velocity", "data=cmu"], tmp_path / "b")
    assert Path(str(baseline.hydra.run.dir)).parent.name == f"zero_velocity_cmu{suffix}"


# ----------------------------- row 10: damaged checkpoints, a wrong MOTION_ARCHIVES
class _NotTensors:
    pass


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        ("truncated", "the file is damaged: cut short, the end of its zip archive is missing"),
        ("text", "it was not written by torch.save (it is not a zip archive"),
        ("empty", "the file is empty"),
        ("pickled_object", "it holds Python objects besides tensors and plain containers"),
    ],
)
def test_row_10_an_unreadable_checkpoint_says_why_in_whole_words(content, reason, tmp_path):
    """torch's message used to be cut mid-word ("...transferred incorrectly, o.") for a file
    cut short, and was "101." for a text file."""
    import torch

    from src.lit.checkpoints import CheckpointError, read_checkpoint

    path = tmp_path / "x.ckpt"
    if content == "truncated":
        torch.save({"state_dict": {"w": torch.zeros(1000)}, "motion": {}}, path)
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif content == "text":
        path.write_text("epoch,loss\n1,0.5\n")
    elif content == "empty":
        path.write_bytes(b"")
    else:
        torch.save({"state_dict": {}, "motion": _NotTensors()}, path)
    with pytest.raises(CheckpointError) as err:
        read_checkpoint(path)
    assert str(err.value) == (
        f"cannot read checkpoint {path}: {reason}"
        + str(err.value).split(reason, 1)[1]  # the rest of the reason, then the fix
    )
    assert str(err.value).endswith(". Use another checkpoint of the run (last.ckpt, best-*.ckpt).")
    assert "\n" not in str(err.value) and "101" not in str(err.value)


def test_row_10_a_wrong_motion_archives_says_the_folder_does_not_exist(tmp_path, monkeypatch):
    from src.data.archive import ensure_dataset
    from src.data.errors import DataError

    wrong = tmp_path / "no_such_folder"
    monkeypatch.setenv("MOTION_ARCHIVES", str(wrong))
    # paths.archive_dir is ${oc.env:MOTION_ARCHIVES}: the same folder comes twice.
    with pytest.raises(DataError) as err:
        ensure_dataset("h36m", tmp_path / "data", archive_dir=str(wrong))
    first = str(err.value).splitlines()[0]
    assert first.count(str(wrong / "h3.6m.zip")) == 1, first
    assert first.endswith(f"; MOTION_ARCHIVES={wrong}: that folder does not exist."), first
    # A folder that exists but lacks the archive is not said to be missing.
    wrong.mkdir()
    with pytest.raises(DataError) as err:
        ensure_dataset("h36m", tmp_path / "data", archive_dir=str(wrong))
    assert "does not exist" not in str(err.value).splitlines()[0]


# ------------------------------------------------------------ row 12: train --help
def test_row_12_train_help_is_written_and_lists_every_group_from_conf(help_text):
    """It used to print Hydra's default page: 136 lines of raw config."""
    text = help_text("src.train")
    assert len(text.splitlines()) < 70 and "_target_" not in text  # no raw config
    groups = text.split("== Config groups (group=option) ==")[1].split("==")[0]
    listed = dict(re.findall(r"^([\w/]+): (.+)$", groups, flags=re.M))
    assert set(listed) == {g for g in _groups() if g not in ("paths", "hydra")}
    for group, options in listed.items():
        assert options.split(", ") == _options(group), group
    for key in ("iterations=", "val_every=", "seed=", "data.allow_partial=", "resume=",
                "model.optimizer.lr=", "+trainer.precision=", "--cfg job"):  # fmt: skip
        assert key in text, key


# ------------------------------------------------------------ row 13: the README's commands
def _readme_command_lines() -> tuple[str, list[str]]:
    from tests.conftest import ROOT

    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", text, flags=re.S)
    lines = [line.split("  #")[0].strip() for block in blocks for line in block.splitlines()]
    return text, [line for line in lines if line]


def test_row_13_readme_commands_run_in_the_venv_after_the_quickstart():
    """The Usage block's bare `python` was, on a fresh clone, not the venv's: every command
    failed with ModuleNotFoundError."""
    text, lines = _readme_command_lines()
    activate = text.index("source .venv/bin/activate")
    assert activate < text.index("## Usage")
    for line in lines:
        if line.startswith(("python ", "tensorboard ")):  # the venv's, once activated
            assert text.index(line) > activate, line
    assert "about 4 hours" not in text


def _as_composable(args: list[str]) -> list[str]:
    """A README command's overrides, composable: a sweep's first value for each key, and a
    placeholder (<time>) filled in."""
    out = []
    for arg in args:
        if arg == "-m":
            continue
        key, _, value = re.sub(r"<\w+>", "2026-01-01_00-00-00", arg).partition("=")
        if "," in value and not value.startswith("["):
            value = value.split(",")[0]
        out.append(f"{key}={value}")
    return out


def test_row_13_every_readme_command_of_the_entry_points_composes_and_type_checks(tmp_path):
    import shlex

    from src.config import check_types
    from tests.conftest import compose_config

    _, lines = _readme_command_lines()
    entries = r"(\.venv/bin/)?python -m src\.(train|eval|visualize|export_windows)\b"
    commands = [line for line in lines if re.match(entries, line)]
    assert len(commands) >= 15
    for line in commands:
        words = shlex.split(line.split("&&")[-1].strip())
        entry = words[2].removeprefix("src.")
        cfg = compose_config(entry, _as_composable(words[3:]), tmp_path)
        check_types(cfg, entry)
