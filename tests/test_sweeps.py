"""Sweeps end to end on the synthetic dataset, as a user types them: Hydra's basic multirun,
the Optuna sweeper of conf/hparams_search/conv_s2s_optuna.yaml, and the submitit launcher
(local executor, the SLURM code path without a cluster). See docs/cluster.md."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from tests.conftest import refused, run_in_one_process, run_module

# A timestamped sweep folder: a second sweep gets its own, nothing is written over.
SWEEP_DIR = re.compile(r"\d{4}-\d{2}-\d{2}_\d{2}-\d{2}-\d{2}")
# run_module puts paths.log_dir first, where `-m` can no longer follow; this override is its
# equivalent.
MULTIRUN = "hydra.mode=MULTIRUN"
FAST = ["data=synthetic", "iterations=2", "val_every=2", "trainer.accelerator=cpu"]
FAST += ["data.batch_size=4"]


def _sweep_dir(log_dir: Path, task: str) -> Path:
    (sweep,) = (log_dir / task / "multiruns").iterdir()
    assert SWEEP_DIR.fullmatch(sweep.name), sweep.name
    return sweep


def _check_run(folder: Path) -> float:
    """A finished run folder: checkpoints, config and summary; returns its best score."""
    assert (folder / "checkpoints" / "last.ckpt").is_file()
    assert (folder / "config.yaml").is_file() and (folder / ".hydra" / "overrides.yaml").is_file()
    summary = OmegaConf.load(folder / "summary.yaml")
    assert summary.iterations == 2
    assert math.isfinite(summary.best_val_euler_avg)
    return float(summary.best_val_euler_avg)


@pytest.mark.slow
def test_basic_sweep_gives_each_run_a_named_folder(tmp_path, synthetic_data_dir):
    proc = run_module(
        "src.train",
        MULTIRUN,
        "model=gru_s2s",
        "model.net.hidden=16,32",
        *FAST,
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    sweep = _sweep_dir(tmp_path, "train")
    assert (sweep / "multirun.yaml").is_file()
    runs = sorted(p.name for p in sweep.iterdir() if p.is_dir())
    # job number, then the overrides; paths.log_dir is left out (its slashes would nest
    # folders); no "=" or ",", which Hydra's parser would stop at in ckpt_path=<path>
    assert runs == [
        f"{n}_data.batch_size-4+data-synthetic+iterations-2+model.net.hidden-{h}"
        "+model-gru_s2s+val_every-2"
        for n, h in ((0, 16), (1, 32))
    ]
    for name, hidden in zip(runs, (16, 32), strict=True):
        _check_run(sweep / name)
        assert OmegaConf.load(sweep / name / "config.yaml").model.net.hidden == hidden


@pytest.mark.slow
def test_optuna_sweep_writes_best_trial_beside_the_trials(tmp_path, synthetic_data_dir):
    proc = run_module(
        "src.train",
        MULTIRUN,
        "hparams_search=conv_s2s_optuna",
        "hydra.sweeper.n_trials=2",
        "model.net.nf=2",
        *FAST,
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    sweep = _sweep_dir(tmp_path, "optuna")
    scores = [_check_run(sweep / f"trial_{n}") for n in range(2)]
    result = OmegaConf.load(sweep / "optimization_results.yaml")
    # The study minimised exactly what each trial's summary records.
    assert result.best_value == pytest.approx(min(scores), rel=1e-6)
    assert set(result.best_params) == {
        "model.optimizer.lr",
        "adversarial.lambda_adv",
        "sampling",
        "model.net.C",
    }
    assert result.best_params["model.net.C"] in (5, 10, 20)
    assert 1e-5 <= result.best_params["model.optimizer.lr"] <= 1e-3
    best = scores.index(min(scores))
    drawn = OmegaConf.load(sweep / f"trial_{best}" / "config.yaml")
    assert drawn.model.net.C == result.best_params["model.net.C"]


@pytest.mark.slow
def test_submitit_local_launcher_runs_the_job(tmp_path, synthetic_data_dir):
    proc = run_module(
        "src.train",
        MULTIRUN,
        "hydra/launcher=local",
        "model=gru_s2s",
        "model.net.hidden=16",
        *FAST,
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    sweep = _sweep_dir(tmp_path, "train")
    (run,) = [p for p in sweep.iterdir() if p.is_dir() and not p.name.startswith(".")]
    assert run.name.startswith("0_") and "model.net.hidden-16" in run.name
    _check_run(run)
    # The job went through submitit: its pickled result lies in the sweep's .submitit folder.
    assert list((sweep / ".submitit").glob("*/*_result.pkl"))


@pytest.mark.slow
def test_diverged_run_in_a_sweep_scores_inf_and_the_sweep_goes_on(tmp_path, synthetic_data_dir):
    # An infinite learning rate passes the lr > 0 check and makes the second loss non-finite.
    proc = run_module(
        "src.train",
        MULTIRUN,
        "model=gru_s2s",
        "model.net.hidden=16",
        "model.optimizer.lr=inf",
        *FAST,
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "run diverged, scored +inf" in proc.stdout + proc.stderr
    # Outside a sweep the same run still stops with the one-line error and status 2.
    single = run_module(
        "src.train",
        "model=gru_s2s",
        "model.net.hidden=16",
        "model.optimizer.lr=inf",
        *FAST,
        data_dir=synthetic_data_dir,
        log_dir=tmp_path / "single",
    )
    assert single.returncode == 2
    assert "non-finite loss" in single.stderr


def _error_line(proc) -> str:
    """The one `error: ...` line of a command refused the project's way (status 2)."""
    assert proc.returncode == 2, proc.stderr[-3000:]
    (line,) = [x for x in proc.stderr.splitlines() if x.startswith("error:")]
    return line


def test_a_job_hydra_cannot_compose_refuses_the_sweep_leaving_no_folder(
    tmp_path, synthetic_data_dir
):
    """`-m iterations=2,abc`: Hydra refuses job 1's type (src/config.py's schema); the sweep
    used to be refused only once its folder and multirun.yaml were written."""
    (proc,) = run_in_one_process(
        ["src.train", MULTIRUN, "data=synthetic", "val_every=2", "iterations=2,abc"],
        data_dir=synthetic_data_dir, log_dir=tmp_path,
    )  # fmt: skip
    refused(_error_line(proc), "job 1", "iterations=abc", "Integer")
    assert not list(tmp_path.rglob("*"))


def test_a_bad_value_of_any_job_refuses_the_sweep_before_its_first_job(
    tmp_path, synthetic_data_dir
):
    """`-m iterations=2,-2` used to train job 0, then refuse job 1: with real budgets, hours
    lost. Every job's config is checked as a single run's is, before the first starts; with
    Optuna, the fixed values that every trial shares."""
    base = ["model=gru_s2s", "model.net.hidden=16", "data=synthetic", "val_every=2"]
    basic, optuna = run_in_one_process(
        ["src.train", MULTIRUN, *base, "iterations=2,-2", f"paths.log_dir={tmp_path / 'b'}"],
        ["src.train", MULTIRUN, "hparams_search=conv_s2s_optuna", "data=synthetic",
         "iterations=-2", "val_every=2", f"paths.log_dir={tmp_path / 'o'}"],
        data_dir=synthetic_data_dir, log_dir=None,
    )  # fmt: skip
    # No job started: no checkpoint, no run folder.
    assert not list(tmp_path.rglob("*.ckpt")) and not list(tmp_path.rglob("train.log"))
    assert "Launching" not in basic.stdout + basic.stderr
    line = _error_line(basic)
    # The job by its number and overrides (job 0, iterations=2, is fine), the bad value and
    # what it must be.
    overrides = line.split("(", 1)[1].split(")", 1)[0].split()
    assert "job 1" in line and {"iterations=-2", *base} <= set(overrides), line
    assert "iterations=-2 must be >= 1" in line, line
    assert "iterations=-2 must be >= 1" in _error_line(optuna)
