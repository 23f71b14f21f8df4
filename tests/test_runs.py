"""A run's lifecycle (issue #13): resuming a run by its folder with the run's own settings, run
folders that cannot collide and that a refused run never touches, sweep folders that work as
`ckpt_path=` values, a plain progress line in logs, exact lengths, and debug runs that write
nothing heavy."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf

from src.cli import claim_run_folder
from src.config import ConfigError, check_schedule
from src.lit.callbacks import OffTerminalOnly, progress_line
from src.lit.checkpoints import CheckpointError
from src.prepare import compose_config, describe, restore_run
from tests.conftest import ROOT, run_in_one_process, run_interrupted
from tests.test_resume import TINY

GRU = [
    "data=synthetic",
    "model=gru_s2s",
    "model.net.hidden=16",
    "data.batch_size=4",
    "trainer=cpu",
    "trainer.enable_progress_bar=false",
    "media_every=0",
]

# A run that dies right after last.ckpt holds iteration $DIE_AFTER, with no cleanup (as after
# SIGKILL), loaded through PYTHONPATH: the interruption always falls at the same iteration.
DIE_AFTER_SAVE = """
import os
import time

from src.lit.checkpoints import LastCheckpoint

_save = LastCheckpoint.save


def _save_then_die(self, trainer, pl_module):
    dies = pl_module.global_step == int(os.environ["DIE_AFTER"])
    if dies:  # training time that only the checkpoint can carry to the resumed run
        time.sleep(float(os.environ.get("SLEEP_BEFORE", "0")))
    _save(self, trainer, pl_module)
    if dies:
        os._exit(137)


LastCheckpoint.save = _save_then_die
"""


def _env(data_dir: Path, **extra: str) -> dict[str, str]:
    # One thread: the same kernels in every run (bit-for-bit comparisons), and no
    # oversubscription of a shared machine.
    env = {**os.environ, "MOTION_DATA_DIR": str(data_dir), "OMP_NUM_THREADS": "1"}
    return {**env, "PYTHONUNBUFFERED": "1", **extra}


def _cmd(module: str, log_dir: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", module, f"paths.log_dir={log_dir}", *args]


def _cli(module: str, log_dir: Path, data_dir: Path, *args: str, **env: str):
    return subprocess.run(
        _cmd(module, log_dir, *args),
        cwd=ROOT,
        env=_env(data_dir, **env),
        capture_output=True,
        text=True,
        timeout=600,
    )


def _runs(log_dir: Path, task: str = "train") -> list[Path]:
    return sorted((log_dir / task / "runs").glob("*/*"))


def _error_line(proc) -> str:
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error: ")]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    return lines[0]


# ------------------------------------------------------------------ resume a run, not a config
def _fake_run(folder: Path, data_dir: Path, *overrides: str, cli: bool = True) -> Path:
    """A run folder as training leaves it (config.yaml resolved, checkpoints/last.ckpt; from
    the command line, also Hydra's record of the config-group options), without training: the
    resume logic reads only these files."""
    cfg = compose_config("train", list(overrides), folder, data_dir)
    task = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])
    folder.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(task, folder / "config.yaml", resolve=True)
    if cli:
        choices = {"hydra": {"runtime": {"choices": cfg.hydra.runtime.choices}}}
        (folder / ".hydra").mkdir()
        OmegaConf.save(OmegaConf.create(choices), folder / ".hydra" / "hydra.yaml")
    (folder / "checkpoints").mkdir()
    (folder / "checkpoints" / "last.ckpt").write_bytes(b"")
    return folder


def _restore(out: Path, data_dir: Path, *overrides: str):
    cfg = compose_config("train", list(overrides), out, data_dir)
    hydra_cfg = HydraConfig.get()
    choices = OmegaConf.to_container(hydra_cfg.runtime.choices)
    return restore_run(cfg, list(hydra_cfg.overrides.task), choices)


RUN = [*GRU, "iterations=6", "val_every=2", "seed=7", "model.optimizer.lr=0.01"]


@pytest.mark.parametrize("how", ["resume", "ckpt_path"])
def test_resume_restores_the_runs_own_settings(how, tmp_path, synthetic_data_dir):
    run = _fake_run(tmp_path / "run", synthetic_data_dir, *RUN)
    target = f"resume={run}" if how == "resume" else f"ckpt_path={run}/checkpoints/last.ckpt"
    cfg, resume = _restore(tmp_path / "new", synthetic_data_dir, target)
    assert resume is not None and resume.run_dir == run
    # The defaults would be conv_s2s on h36m, 20000 iterations, validation every 1000.
    assert (cfg.model.name, cfg.data.name, cfg.run_name) == (
        "gru_s2s",
        "synthetic",
        "gru_s2s_synthetic",
    )
    assert (cfg.iterations, cfg.val_every, cfg.seed) == (6, 2, 7)
    assert cfg.model.net.hidden == 16 and cfg.model.optimizer.lr == 0.01
    assert cfg.ckpt_path == str(run / "checkpoints" / "last.ckpt")
    # Where files live is this command's: the new run writes into its own folder.
    assert cfg.paths.output_dir == str(tmp_path / "new")
    assert cfg.data.data_dir == str(synthetic_data_dir)


def test_a_checkpoint_away_from_its_run_folder_resumes_with_the_command_lines_schedule(
    tmp_path, synthetic_data_dir
):
    """No config.yaml beside the checkpoint: its stored sections (model, data, ...) are the
    run's; what it does not store (length, schedule, seed) is the command line's, accepted."""
    run_cfg = compose_config("train", RUN, tmp_path / "run", synthetic_data_dir)
    sections = {
        k: OmegaConf.to_container(run_cfg[k], resolve=True)
        for k in ("model", "data", "sampling", "adversarial", "metrics")
    }
    ckpt = tmp_path / "copied.ckpt"
    torch.save({"motion": {"config": sections}, "state_dict": {}}, ckpt)
    cfg, resume = _restore(tmp_path / "new", synthetic_data_dir, f"ckpt_path={ckpt}", *RUN)
    assert describe(resume, 3).startswith(f"resuming from {ckpt} at iteration 3, with the config")
    assert (cfg.iterations, cfg.val_every, cfg.seed) == (6, 2, 7)
    assert cfg.model.net.hidden == 16 and cfg.model.optimizer.lr == 0.01
    # What the checkpoint stores still may not change.
    with pytest.raises(CheckpointError, match="model.optimizer.lr: checkpoint 0.01, command line"):
        _restore(tmp_path / "new2", synthetic_data_dir, f"ckpt_path={ckpt}", *RUN[:-1])


def test_resume_applies_length_and_trainer_overrides_on_top(tmp_path, synthetic_data_dir):
    run = _fake_run(tmp_path / "run", synthetic_data_dir, *RUN)
    cfg, resume = _restore(
        tmp_path / "new",
        synthetic_data_dir,
        f"resume={run}",
        "iterations=10",
        "trainer.accelerator=cpu",
        "checkpoint_every=0",
        # The run's own values, repeated: accepted.
        "data=synthetic",
        "model=gru_s2s",
        "model.net.hidden=16",
    )
    assert (cfg.iterations, cfg.val_every, cfg.checkpoint_every) == (10, 2, 0)
    assert cfg.trainer.accelerator == "cpu" and cfg.model.net.hidden == 16
    assert "iterations=10" in resume.applied and "trainer.accelerator=cpu" in resume.applied


@pytest.mark.parametrize(
    ("override", "named"),
    [
        ("seed=1", "seed: checkpoint 7, command line 1"),
        ("val_every=3", "val_every: checkpoint 2, command line 3"),
        ("model.optimizer.lr=0.1", "model.optimizer.lr: checkpoint 0.01, command line 0.1"),
        ("data=cmu", "data=cmu: the run used data=synthetic"),
        ("model=conv_s2s", "model=conv_s2s: the run used model=gru_s2s"),
        ("+trainer.precision=bf16-mixed", "trainer.precision: checkpoint absent, command line"),
        # Compiled dropout draws other masks than eager: the resume would not be exact.
        ("compile.enabled=true", "compile.enabled: checkpoint False, command line True"),
    ],
)
def test_resume_with_other_settings_is_refused_naming_them(
    override, named, tmp_path, synthetic_data_dir
):
    run = _fake_run(tmp_path / "run", synthetic_data_dir, *RUN)
    with pytest.raises(CheckpointError, match="with settings other than its run's") as err:
        _restore(tmp_path / "new", synthetic_data_dir, f"resume={run}", override)
    assert named in str(err.value)


def test_trainer_options_beside_a_resume_keep_the_runs_precision(tmp_path, synthetic_data_dir):
    """Trainer keys may change on resume (device settings), except trainer.precision, which
    changes the numbers: a bf16-mixed run stays bf16-mixed under trainer=cpu, and a float32
    run stays float32."""
    bf16 = _fake_run(tmp_path / "bf16", synthetic_data_dir, *RUN, "+trainer.precision=bf16-mixed")
    cfg, _ = _restore(tmp_path / "a", synthetic_data_dir, f"resume={bf16}", "trainer=cpu")
    assert cfg.trainer.precision == "bf16-mixed" and cfg.trainer.accelerator == "cpu"
    fp32 = _fake_run(tmp_path / "fp32", synthetic_data_dir, *RUN)
    cfg, _ = _restore(tmp_path / "b", synthetic_data_dir, f"resume={fp32}", "trainer=cpu")
    assert "precision" not in cfg.trainer
    cfg, _ = _restore(tmp_path / "c", synthetic_data_dir, f"resume={fp32}", "trainer.devices=1")
    assert cfg.trainer.devices == 1


def test_run_without_recorded_options_compares_a_group_by_its_values(tmp_path, synthetic_data_dir):
    """A run trained in-process (a notebook, the tests) has no .hydra/hydra.yaml: a group option
    beside its resume is accepted when it gives the run's values, refused naming the others."""
    run = _fake_run(tmp_path / "run", synthetic_data_dir, *RUN, cli=False)
    cfg, _ = _restore(tmp_path / "new", synthetic_data_dir, f"resume={run}", *RUN)
    assert cfg.iterations == 6 and cfg.model.net.hidden == 16
    with pytest.raises(CheckpointError) as err:
        _restore(tmp_path / "new2", synthetic_data_dir, f"resume={run}", "data=cmu")
    assert "data.name: checkpoint synthetic, command line cmu (from data=cmu" in str(err.value)


def test_resume_and_ckpt_path_naming_two_checkpoints_is_refused(tmp_path, synthetic_data_dir):
    run = _fake_run(tmp_path / "run", synthetic_data_dir, *RUN)
    with pytest.raises(ConfigError, match="name different checkpoints"):
        _restore(
            tmp_path / "new", synthetic_data_dir, f"resume={run}", f"ckpt_path={tmp_path}/x.ckpt"
        )


@pytest.mark.slow
def test_resumed_run_ends_where_the_uninterrupted_run_ends(tmp_path, synthetic_data_dir):
    """The README's resume line, with no override but where files live: the run's own length
    and validation schedule (not the defaults), and the uninterrupted run's result."""
    run_args = [*TINY, "checkpoint_every=0"]  # TINY: iterations=6 val_every=2, adversarial on
    whole = _cli("src.train", tmp_path / "a", synthetic_data_dir, *run_args)
    assert whole.returncode == 0, whole.stderr[-3000:]
    (run_a,) = _runs(tmp_path / "a")

    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(DIE_AFTER_SAVE)
    path = os.pathsep.join([str(hook), str(ROOT)])
    died = _cli(
        "src.train", tmp_path / "b", synthetic_data_dir, *run_args, PYTHONPATH=path,
        DIE_AFTER="2", SLEEP_BEFORE="3",
    )  # fmt: skip
    assert died.returncode == 137, died.stderr[-3000:]
    (run_b,) = _runs(tmp_path / "b")
    assert not (run_b / "summary.yaml").exists()
    first = torch.load(run_b / "checkpoints" / "last.ckpt", weights_only=False)

    resumed = _cli("src.train", tmp_path / "b", synthetic_data_dir, f"resume={run_b}")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resuming the run {run_b} at iteration 2" in resumed.stdout
    assert _runs(tmp_path / "b") == [run_b]  # in its own folder, not a new one
    new = run_b
    config = OmegaConf.load(new / "config.yaml")
    assert (config.iterations, config.val_every, config.model.net.nf) == (6, 2, 2)

    sum_a = OmegaConf.to_container(OmegaConf.load(run_a / "summary.yaml"))
    sum_b = OmegaConf.to_container(OmegaConf.load(new / "summary.yaml"))
    assert sum_b["iterations"] == sum_a["iterations"] == 6
    for key in ("final_val_euler_avg", "final_val_mpjpe_avg", "best_val_euler_avg"):
        assert sum_b[key] == sum_a[key], key  # exact: bit for bit on CPU
    # Training time: the first segment's (3 s of sleep in it) carried over by the checkpoint.
    t1 = first["callbacks"]["Timer"]["time_elapsed"]["train"]
    assert t1 >= 3
    # This process's training alone cannot exceed its own wall time; with t1 carried, it does.
    assert sum_b["wall_time_s"] < sum_b["train_time_s"] <= t1 + sum_b["wall_time_s"]
    assert sum_b["train_time_s"] > t1
    assert (sum_a["resumed_at"], sum_b["resumed_at"]) == (None, 2)
    assert sum_a["train_time_s"] <= sum_a["wall_time_s"]
    # From a checkpoint without the Timer's state (src.train before it kept one), the total is
    # unknown: null, not this process's time passed off as the whole.
    del first["callbacks"]["Timer"]
    torch.save(first, tmp_path / "older.ckpt")
    older = _cli(
        "src.train", tmp_path / "c", synthetic_data_dir, *run_args,
        f"ckpt_path={tmp_path / 'older.ckpt'}",
    )  # fmt: skip
    assert older.returncode == 0, older.stderr[-8000:]
    (run_c,) = _runs(tmp_path / "c")
    sum_c = OmegaConf.to_container(OmegaConf.load(run_c / "summary.yaml"))
    assert (sum_c["train_time_s"], sum_c["resumed_at"]) == (None, 2)
    assert sum_c["final_val_euler_avg"] == sum_a["final_val_euler_avg"]

    # The finished run has nothing left to do: refused, and no folder is left for it.
    again = _cli("src.train", tmp_path / "a", synthetic_data_dir, f"resume={run_a}")
    assert again.returncode == 2
    assert "nothing to resume" in _error_line(again) and "iterations=N" in _error_line(again)
    assert _runs(tmp_path / "a") == [run_a]
    assert OmegaConf.to_container(OmegaConf.load(run_a / "summary.yaml")) == sum_a
    # As that error says, iterations=N trains it longer: on to N, one more validation period,
    # in its own folder; what the 6 iterations wrote is kept beside.
    longer = _cli(
        "src.train", tmp_path / "a", synthetic_data_dir, f"resume={run_a}", "iterations=8"
    )
    assert longer.returncode == 0, longer.stderr[-3000:]
    assert _runs(tmp_path / "a") == [run_a]
    sum_d = OmegaConf.to_container(OmegaConf.load(run_a / "summary.yaml"))
    assert (sum_d["resumed_at"], sum_d["iterations"]) == (6, 8)
    assert OmegaConf.to_container(OmegaConf.load(run_a / "summary-iter000006.yaml")) == sum_a
    assert OmegaConf.load(run_a / "config-iter000006.yaml").iterations == 6
    assert OmegaConf.load(run_a / "config.yaml").iterations == 8


# ------------------------------------------------------------------ run folders
def test_run_folders_are_claimed_atomically(tmp_path):
    base = tmp_path / "train" / "runs" / "gru_s2s_synthetic" / "2026-01-01_00-00-00"
    got: list[Path] = []
    barrier = threading.Barrier(8)

    def claim():
        barrier.wait()  # all at once: the same timestamped name for each
        got.append(claim_run_folder(base))

    threads = [threading.Thread(target=claim) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(p.name for p in got) == sorted(
        [base.name] + [f"{base.name}-{n}" for n in range(1, 8)]
    )


REFUSED = {
    # A config refused before training (an out-of-range value, checked before the folder is
    # made; a misspelt action, found when the data loads).
    "train_before_the_folder": ["src.train", *GRU, "iterations=2", "sampling.eta=2"],
    "train_when_the_data_loads": ["src.train", *GRU, "iterations=2", "data.actions=[walkin]"],
    # Found after the folder was claimed: a missing checkpoint, a misspelt action.
    "eval_checkpoint": ["src.eval", "ckpt_path=/nonexistent/last.ckpt"],
    "eval_data": ["src.eval", "model=zero_velocity", "data=synthetic", "data.actions=[walkin]"],
    "visualize": ["src.visualize", "model=zero_velocity", "data=synthetic", "action=walkin"],
    "length": ["src.train", *GRU, "iterations=3", "val_every=2"],
    "max_epochs": ["src.train", *GRU, "iterations=100", "val_every=100", "trainer.max_epochs=5"],
}


@pytest.fixture(scope="module")
def refused_runs(tmp_path_factory, synthetic_data_dir):
    """Each REFUSED command (one process for all), with what it left in its own log folder."""
    root = tmp_path_factory.mktemp("refused")
    procs = run_in_one_process(
        *([m, f"paths.log_dir={root / name}", *args] for name, (m, *args) in REFUSED.items()),
        data_dir=synthetic_data_dir, log_dir=None,
    )  # fmt: skip
    return {name: (proc, root / name) for name, proc in zip(REFUSED, procs, strict=True)}


def _left_nothing(name: str, refused_runs) -> None:
    proc, log_dir = refused_runs[name]
    assert proc.returncode == 2, proc.stderr[-3000:]
    _error_line(proc)
    assert not log_dir.exists() or not list(log_dir.rglob("*")), list(log_dir.rglob("*"))


@pytest.mark.parametrize("name", ["train_before_the_folder", "train_when_the_data_loads"])
def test_refused_config_creates_no_run_folder(name, refused_runs):
    """Every refused run used to leave a folder with Hydra's files behind."""
    _left_nothing(name, refused_runs)


@pytest.mark.parametrize("name", ["eval_checkpoint", "eval_data", "visualize"])
def test_refused_eval_or_visualize_creates_no_folder(name, refused_runs):
    """As for src.train: a refusal found after the folder was claimed used to leave a folder
    with the log and Hydra's files behind."""
    _left_nothing(name, refused_runs)


def test_a_named_folder_holding_a_run_is_left_untouched(tmp_path, synthetic_data_dir):
    """hydra.run.dir=<a run's folder>: refused before Hydra writes anything (it used to
    replace the run's .hydra/config.yaml and overrides.yaml)."""
    run = tmp_path / "run"
    for name, text in {
        ".hydra/config.yaml": "seed: 1\n",
        ".hydra/overrides.yaml": "- seed=1\n",
        "config.yaml": "seed: 1\n",
        "train.log": "the run's log\n",
        "checkpoints/last.ckpt": "weights",
    }.items():
        (run / name).parent.mkdir(parents=True, exist_ok=True)
        (run / name).write_text(text)
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    proc = _cli("src.train", tmp_path, synthetic_data_dir, *GRU, f"hydra.run.dir={run}")
    assert proc.returncode == 2
    assert "already holds a run; nothing was written to it" in _error_line(proc)
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before


def _interrupted_line(proc) -> str:
    """The one line a Ctrl-C ends a command with: status 130, no traceback, not Lightning's."""
    output = proc.stdout + proc.stderr
    assert proc.returncode == 130, output[-3000:]
    assert "Traceback" not in output and "KeyboardInterrupt" not in output, output[-3000:]
    (line,) = [x for x in proc.stderr.splitlines() if "Ctrl-C" in x]
    return line


@pytest.mark.slow
def test_ctrl_c_in_eval_leaves_no_half_written_folder_and_what_was_there(
    tmp_path, synthetic_data_dir
):
    """Ctrl-C during src.eval's test loop (Lightning's Trainer exited 1 with its own line)
    and while it writes its results (results.md written, results.json not yet): status 130,
    one line, and of the folder only what a user had put there before."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's")
    args = ["model=zero_velocity", "data=synthetic", "trainer=cpu"]
    at_test = ("src.lit.predictor:MotionPredictor", "predict_windows")
    proc = run_interrupted(
        at_test, 0, "src.eval", *args, f"hydra.run.dir={mine}",
        data_dir=synthetic_data_dir, log_dir=tmp_path / "logs",
    )  # fmt: skip
    assert str(mine) in _interrupted_line(proc)
    assert os.listdir(mine) == ["notes.txt"] and (mine / "notes.txt").read_text() == "the user's"
    # Its own timestamped folder: removed, while an earlier evaluation's stays as it was.
    log_dir = tmp_path / "logs"
    earlier = log_dir / "eval" / "runs" / "zero_velocity_synthetic" / "2000-01-01_00-00-00"
    earlier.mkdir(parents=True)
    (earlier / "results.json").write_text("{}")
    proc = run_interrupted(
        ("src.results", "tables_csv"), 0, "src.eval", *args,
        data_dir=synthetic_data_dir, log_dir=log_dir,
    )  # fmt: skip
    line = _interrupted_line(proc)
    assert "removed" in line, line
    assert [p.relative_to(log_dir) for p in log_dir.rglob("*") if p.is_file()] == [
        earlier.relative_to(log_dir) / "results.json"
    ]


@pytest.mark.slow
def test_four_concurrent_runs_get_four_folders(tmp_path, synthetic_data_dir):
    cmd = _cmd("src.train", tmp_path, *GRU, "iterations=2", "val_every=2")
    procs = [
        subprocess.Popen(
            cmd,
            cwd=ROOT,
            env=_env(synthetic_data_dir),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )  # fmt: skip
        for _ in range(4)
    ]
    for proc in procs:
        out, _ = proc.communicate(timeout=600)
        assert proc.returncode == 0, out[-3000:]
    runs = _runs(tmp_path)
    assert len(runs) == 4 and len({r.parent for r in runs}) == 1
    for run in runs:
        assert [p.name for p in (run / "checkpoints").glob("last*.ckpt")] == ["last.ckpt"]
        assert len(list((run / "checkpoints").glob("best-*.ckpt"))) == 1
        assert len(list((run / "tensorboard").glob("events.out.tfevents.*"))) == 1
        summary = OmegaConf.load(run / "summary.yaml")
        assert summary.last_checkpoint == str(run / "checkpoints" / "last.ckpt")
        assert Path(summary.best_checkpoint).parent == run / "checkpoints"


# ------------------------------------------------------------------ sweep folders
def test_sweep_job_folder_works_as_ckpt_path(tmp_path):
    """A sweep job's folder holds no character Hydra's override parser stops at: its
    checkpoint path works as `ckpt_path=<path>` exactly as printed, without quotes."""
    overrides = [
        "model=gru_s2s",
        "data=synthetic",
        "model.optimizer.lr=0.001",
        "data.actions=[walking,eating]",
        "sampling.eta=0.5",
        "run_name='a b'",
    ]
    cfg = compose_config("train", overrides, tmp_path)
    name = str(cfg.hydra.sweep.subdir)
    assert name.startswith("0_") and "model-gru_s2s" in name and "model.optimizer.lr-0.001" in name
    path = f"{tmp_path}/multiruns/2026-01-01_00-00-00/{name}/checkpoints/last.ckpt"
    (parsed,) = OverridesParser.create().parse_overrides([f"ckpt_path={path}"])
    assert parsed.value() == path
    assert compose_config("eval", [f"ckpt_path={path}"], tmp_path / "e").ckpt_path == path


@pytest.mark.slow
def test_printed_checkpoint_of_a_sweep_job_evaluates(tmp_path, synthetic_data_dir):
    proc = _cli(
        "src.train", tmp_path, synthetic_data_dir, "hydra.mode=MULTIRUN", *GRU,
        "iterations=2", "val_every=2", "data.actions=[walking,eating]",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    (line,) = [x for x in proc.stdout.splitlines() if "last checkpoint: " in x]
    ckpt = line.split("last checkpoint: ", 1)[1].strip()
    assert Path(ckpt).is_file() and "=" not in ckpt and "," not in ckpt
    evaluated = _cli("src.eval", tmp_path, synthetic_data_dir, f"ckpt_path={ckpt}", "trainer=cpu")
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]


# ------------------------------------------------------------------ progress
def test_progress_line_reads_at_a_glance():
    line = progress_line(120, 20000, 0.61, {"loss_g": 0.04123, "loss_d": 1.3862})
    assert line == (
        "iteration 120/20000 (0.6%) | 0.61 it/s | ETA 9h03m | loss_g 0.04123 loss_d 1.386"
    )
    assert "ETA ?" in progress_line(0, 10, 0.0, {})


def test_progress_goes_to_the_console_only_off_a_terminal(monkeypatch):
    record = logging.LogRecord("src.lit.callbacks", logging.INFO, "", 0, "iteration 1/2", (), None)
    other = logging.LogRecord("src.train", logging.INFO, "", 0, "run folder", (), None)

    class Stdout:
        def __init__(self, tty):
            self.tty = tty

        def isatty(self):
            return self.tty

    monkeypatch.setattr(sys, "stdout", Stdout(True))
    assert not OffTerminalOnly().filter(record) and OffTerminalOnly().filter(other)
    monkeypatch.setattr(sys, "stdout", Stdout(False))
    assert OffTerminalOnly().filter(record)


def test_progress_line_in_train_log_and_redirected_stdout(tmp_path, synthetic_data_dir):
    proc = _cli(
        "src.train", tmp_path, synthetic_data_dir, *GRU, "iterations=4", "val_every=2",
        "progress_every_s=0",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run,) = _runs(tmp_path)
    log_lines = [
        x for x in (run / "train.log").read_text().splitlines() if "[src.lit.callbacks]" in x
    ]
    out_lines = [x for x in proc.stdout.splitlines() if "[src.lit.callbacks]" in x]
    assert len(log_lines) == len(out_lines) == 4
    assert "iteration 4/4 (100.0%)" in log_lines[-1]
    for part in ("it/s", "ETA", "loss_recon", "loss_g"):
        assert part in log_lines[0] and part in out_lines[0]


# ------------------------------------------------------------------ exact lengths
@pytest.mark.parametrize(
    ("iterations", "val_every", "fix"),
    [
        (3, 2, "use iterations=2 or iterations=4, or val_every=1"),
        (2, 5, "iterations=5, or val_every=2"),
    ],
)
def test_length_that_does_not_fit_the_validation_schedule_is_refused(
    iterations, val_every, fix, train_cfg
):
    from src.train import train

    gru = [o for o in GRU if not o.startswith(("data=", "trainer="))]  # train_cfg has them
    cfg = train_cfg(*gru, f"iterations={iterations}", f"val_every={val_every}")
    with pytest.raises(ConfigError, match=f"iterations={iterations} is not a multiple of") as err:
        train(cfg)  # it used to train 4 (or 5) iterations
    assert fix in str(err.value)
    check_schedule(train_cfg(*gru, "iterations=6", "val_every=2"))  # a multiple passes


def test_cli_refuses_a_length_that_does_not_fit(refused_runs):
    _left_nothing("length", refused_runs)
    line = _error_line(refused_runs["length"][0])
    assert line.startswith("error: iterations=3 is not a multiple of val_every=2")


# ------------------------------------------------------------------ debug runs
def test_fast_dev_run_writes_nothing_heavy_where_the_readme_says(tmp_path, synthetic_data_dir):
    proc = _cli(
        "src.train", tmp_path, synthetic_data_dir, "debug=fast_dev_run", "data=synthetic",
        "model=conv_s2s", "model.net.nf=2", "model.net.d_z=8", "adversarial.discriminator.nf=2",
        "adversarial.discriminator.d_z=8", "adversarial.discriminator.d_fc=8",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run,) = _runs(tmp_path, "debug")
    written = sorted(str(p.relative_to(run)) for p in run.rglob("*") if p.is_file())
    assert not [p for p in written if p.endswith(".ckpt") or "tfevents" in p], written
    assert "outputs/debug" in (ROOT / "README.md").read_text()


def test_resume_names_the_run_folder_or_its_checkpoints_folder(tmp_path):
    """resume=<run>/checkpoints used to look for <run>/checkpoints/checkpoints/last.ckpt."""
    from src.prepare import checkpoint_to_resume

    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    last.parent.mkdir(parents=True)
    last.write_bytes(b"")
    for given in (last.parent.parent, last.parent, last):
        assert checkpoint_to_resume(OmegaConf.create({"resume": str(given)})) == last


# ------------------------------------------------------------------ one way for each job
def test_an_atomic_write_leaves_the_old_file_or_the_new_one(tmp_path):
    """Every writer of src (checkpoints, the data cache, synthetic files, exported windows)
    goes through atomic_write; a write that dies midway leaves the previous file whole."""
    import numpy as np

    from src.data.files import atomic_write

    path = tmp_path / "x.npy"
    path.write_bytes(b"old")

    def dies_midway(tmp: Path) -> None:
        tmp.write_bytes(b"ne")
        raise OSError("killed mid-write")

    with pytest.raises(OSError, match="killed mid-write"):
        atomic_write(path, dies_midway)
    assert path.read_bytes() == b"old" and list(tmp_path.iterdir()) == [path]
    atomic_write(path, lambda tmp: np.save(tmp, np.arange(3)))  # np.save keeps the name
    assert np.load(path).tolist() == [0, 1, 2] and list(tmp_path.iterdir()) == [path]


def test_a_training_config_is_restored_and_checked_once(tmp_path, synthetic_data_dir, monkeypatch):
    """The command line's callback restores and checks a resumed run's config before its
    folder exists; src.train then finds it prepared (both used to do it, at every start)."""
    import src.prepare as resume
    import src.train
    from src.cli import hydra_entry

    run = _fake_run(tmp_path / "run", synthetic_data_dir, *RUN)
    calls = []
    restore = resume.restore_run
    monkeypatch.setattr(resume, "restore_run", lambda *a: calls.append(a) or restore(*a))

    class Prepared(Exception):
        pass

    def stop(data_cfg):  # the first thing train() does after preparing: load the data
        raise Prepared(data_cfg.name)

    monkeypatch.setattr(src.train, "build_datamodule", stop)
    monkeypatch.setenv("MOTION_DATA_DIR", str(synthetic_data_dir))
    argv = ["src.train", f"resume={run}", "iterations=8", f"paths.log_dir={tmp_path / 'logs'}"]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(Prepared, match="synthetic"):
        hydra_entry("train")(src.train.train)()
    assert len(calls) == 1


def test_resume_with_a_length_that_does_not_fit_suggests_lengths_only(tmp_path, synthetic_data_dir):
    """`resume=<run> iterations=7` used to suggest val_every=7, which the resume refuses (a
    resumed run keeps its val_every): only lengths are suggested."""
    from src.prepare import prepare_training

    run = _fake_run(tmp_path / "run", synthetic_data_dir, *RUN)  # val_every=2
    overrides = [f"resume={run}", "iterations=7"]
    cfg = compose_config("train", overrides, tmp_path / "new", synthetic_data_dir)
    choices = OmegaConf.to_container(HydraConfig.get().runtime.choices)
    with pytest.raises(ConfigError) as err:
        prepare_training(cfg, overrides, choices)
    assert str(err.value) == (
        "iterations=7 is not a multiple of val_every=2 (training runs whole validation "
        "periods); use iterations=6 or iterations=8 (a resume keeps its run's val_every)."
    )


@pytest.mark.parametrize(
    "override",
    ["+trainer.max_steps=5", "trainer.max_epochs=5", "+trainer.min_steps=2",
     "+trainer.min_epochs=2", "+trainer.val_check_interval=3", "trainer.check_val_every_n_epoch=2",
     "+trainer.limit_train_batches=3"],
)  # fmt: skip
def test_trainer_keys_the_schedule_sets_are_refused_naming_iterations(override, train_cfg):
    """`+trainer.max_steps=N` used to be accepted and recorded in config.yaml while the run
    trained `iterations`; each Trainer key the iteration schedule sets is refused, naming it."""
    from src.config import check

    key, _, value = override.lstrip("+").partition("=")
    with pytest.raises(ConfigError) as err:
        check(train_cfg(override), "train")
    assert str(err.value).startswith(
        f"{key}={value}: the training schedule sets it from iterations=4 (the run's length) "
        "and val_every=2; change those instead."
    )


def test_cli_refuses_max_epochs_beside_iterations(refused_runs):
    """As a new user would try it: trains nothing, leaves no folder."""
    _left_nothing("max_epochs", refused_runs)
    line = _error_line(refused_runs["max_epochs"][0])
    assert line.startswith("error: trainer.max_epochs=5: the training schedule")
