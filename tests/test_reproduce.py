"""One command reproduces the papers' tables: `python -m src.train -m reproduce=papers` sweeps
every reproducible row over 3 seeds (conf/reproduce/), the joblib launcher runs several jobs at
once (conf/hydra/launcher/joblib.yaml), and `python -m src.report <multirun>` makes the page."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pandas as pd
import pytest
import yaml
from omegaconf import OmegaConf

from src.prepare import compose_config
from tests.conftest import CONF, run_module

CORE = ["li2018_h36m", "li2018_cmu", "martinez2017_res_sup"]
# Li et al. Tables 5 and 6 (Table 4 is li2018_cmu's average), Martinez et al.'s other rows.
REST = [
    "li2018_h36m_no_long_term",
    "li2018_h36m_kernel_4x4",
    "li2018_h36m_kernel_7x2",
    "martinez2017_res_unsup",
    "martinez2017_untied",
    "martinez2017_sampling_sa",
    "martinez2017_res_sa",
    "martinez2017_zero_noise_sa",
]


def _listed_in_train_defaults() -> bool:
    defaults = OmegaConf.to_container(OmegaConf.load(CONF / "train.yaml").defaults)
    return any("reproduce" in str(entry) for entry in defaults)


def reproduce(name: str) -> str:
    """The override that selects conf/reproduce/<name>.yaml (`reproduce=` once train.yaml lists
    the group, `+reproduce=` before)."""
    return f"reproduce={name}" if _listed_in_train_defaults() else f"+reproduce={name}"


def sweep_params(name: str) -> dict[str, list[str]]:
    cfg = compose_config("train", [reproduce(name)], "/tmp/unused")
    params = cfg.hydra.sweeper.params
    return {k: [v.strip() for v in str(params[k]).split(",")] for k in params}


def test_the_documented_command_needs_no_plus():
    """`python -m src.train -m reproduce=papers` as the README says: conf/train.yaml lists the
    group (`- optional reproduce: null` in its defaults, after the experiment)."""
    assert _listed_in_train_defaults(), (
        "conf/train.yaml's defaults lack `- optional reproduce: null`; without it the command "
        "must be written `+reproduce=papers`"
    )


def test_papers_sweeps_every_row_core_first_over_three_seeds():
    params = sweep_params("papers")
    assert params["experiment"] == CORE + REST
    assert params["seed"] == ["1", "2", "3"]
    existing = {p.stem for p in (CONF / "experiment").glob("*.yaml")}
    assert set(params["experiment"]) <= existing
    core = sweep_params("papers_core")
    assert core == {"experiment": CORE, "seed": ["1", "2", "3"]}


@pytest.mark.parametrize("experiment", CORE + REST)
def test_budget_overrides_win_over_the_experiments(experiment, tmp_path):
    own = compose_config("train", [reproduce("papers"), f"experiment={experiment}"], tmp_path)
    assert own.run_name == experiment and own.task_name == "reproduce"
    # The paper's schedule unless the command line says otherwise.
    assert own.iterations in (20000, 100000) and own.val_every in (1000, 2000)
    budget = compose_config(
        "train",
        [
            reproduce("papers"),
            f"experiment={experiment}",
            "seed=2",
            "iterations=4000",
            "val_every=500",
            "trainer=gpu",
        ],
        tmp_path,
    )
    assert (budget.iterations, budget.val_every, budget.seed) == (4000, 500, 2)
    assert budget.trainer.accelerator == "gpu" and budget.data.seed == 2
    # Everything else is the experiment's.
    assert budget.model == own.model and budget.data.name == own.data.name


def test_joblib_launcher_config_is_the_plugins_with_a_job_count(tmp_path):
    cfg = compose_config("train", ["hydra/launcher=joblib", "hydra.launcher.n_jobs=3"], tmp_path)
    launcher = cfg.hydra.launcher
    assert launcher._target_.endswith("JoblibLauncher") and launcher.n_jobs == 3
    own = yaml.safe_load((CONF / "hydra" / "launcher" / "joblib.yaml").read_text())
    assert own["n_jobs"] >= 1  # never "all cores" by default: jobs share one GPU


# A tiny conv_s2s with its regulariser, on the synthetic data.
TINY = [
    "data=synthetic",
    "trainer.accelerator=cpu",
    "data.batch_size=4",
    "model.net.nf=2",
    "model.net.d_z=16",
    "adversarial.discriminator.nf=2",
    "adversarial.discriminator.d_z=16",
    "adversarial.discriminator.d_fc=8",
]


@pytest.mark.slow
def test_two_seeds_run_at_once_with_joblib_and_the_report_aggregates_them(
    tmp_path, synthetic_data_dir, monkeypatch
):
    proc = run_module(
        "src.train",
        "hydra.mode=MULTIRUN",
        reproduce("papers_core"),
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
        "experiment=li2018_h36m",  # replaces the sweep's list; seeds 1,2 replace 1,2,3
        "seed=1,2",
        "iterations=6",
        "val_every=2",
        *TINY,
        data_dir=synthetic_data_dir,
        log_dir=tmp_path / "logs",
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Joblib.Parallel(n_jobs=2" in proc.stdout + proc.stderr
    (sweep,) = (tmp_path / "logs" / "reproduce" / "multiruns").iterdir()
    runs = sorted(p for p in sweep.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert [r.name for r in runs] == ["0_li2018_h36m_seed1", "1_li2018_h36m_seed2"]

    # The two jobs overlapped in time: each started (config.yaml is written before training)
    # before the other finished (summary.yaml is written after it).
    spans = [
        ((r / "config.yaml").stat().st_mtime, (r / "summary.yaml").stat().st_mtime) for r in runs
    ]
    (start_a, end_a), (start_b, end_b) = spans
    assert start_a < end_b and start_b < end_a, spans
    for run, seed in zip(runs, (1, 2), strict=True):
        config = yaml.safe_load((run / "config.yaml").read_text())
        assert (config["seed"], config["iterations"], config["run_name"]) == (
            seed,
            6,
            "li2018_h36m",
        )
        summary = yaml.safe_load((run / "summary.yaml").read_text())
        assert summary["iterations"] == 6 and Path(summary["best_checkpoint"]).is_file()

    # The report over the multirun folder: one row, two seeds, best and last.
    monkeypatch.setenv("MOTION_DATA_DIR", str(synthetic_data_dir))
    from src.report import main
    from tests.conftest import compose_config

    out, work = tmp_path / "results.md", tmp_path / "work"
    args = [f"runs=[{sweep}]", f"out={out}", "protocols=[srnn]", "datasets=[]"]
    assert main(compose_config("report", args, work)) == 0  # datasets=[]: no baselines
    page = out.read_text()
    frame = pd.read_csv(work / "results_long.csv")
    frame = frame[(frame.metric == "euler") & frame.value.notna() & (frame.horizon == 80)]
    assert set(frame.experiment) == {"li2018_h36m"} and sorted(set(frame.seed)) == [1, 2]
    # One row of two seeds: Provenance lists a run folder per seed.
    provenance = next(b for b in page.split("\n\n") if "| run folder " in b.split("\n")[0])
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in provenance.splitlines()]
    assert [r[1] for r in rows[2:] if r[0] == "li2018_h36m"] == ["1", "2"], provenance
    for selection in ("best", "last"):
        averages = frame[frame.checkpoint == selection].groupby("seed").value.mean().tolist()
        mean = sum(averages) / 2
        std = abs(averages[0] - averages[1]) / 2**0.5  # sample std of two values
        label = {"best": "best (test-selected)", "last": "last (no test info)"}[selection]
        row = next(line for line in page.splitlines() if f"| {label} " in line)
        assert f" {mean:.2f} ± {std:.2f} " in row, row
    # Both the lean best checkpoint and the resumable last.ckpt were read and evaluated.
    evaluated = [json.loads(p.read_text()) for p in work.glob("*/*_srnn/results.json")]
    checkpoints = {r["provenance"]["checkpoint"] for r in evaluated}
    assert len([c for c in checkpoints if re.fullmatch(r".*best-iter\d{6}\.ckpt", c)]) == 2
    assert all(c.endswith("last.ckpt") or "best-iter" in c for c in checkpoints)

    # Plain run folders give the same page body.
    out2 = tmp_path / "plain.md"
    plain = [f"runs=[{','.join(map(str, runs))}]", f"out={out2}", "protocols=[srnn]", "datasets=[]"]
    assert main(compose_config("report", plain, tmp_path / "work2")) == 0

    def body(text: str) -> str:  # the CSV links and the command name the page's file
        return text.split("## Provenance", 1)[1].split("## Per-action tables", 1)[0]

    assert body(out2.read_text()) == body(page)
