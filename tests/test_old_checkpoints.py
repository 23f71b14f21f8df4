"""Checkpoints written by earlier versions still load in `src.eval` and `MotionForecaster`:
58436ca (the last commit trained on a GPU) and 4b904c1 (before the incremental encoder was
removed and loading became one function). Each commit is checked out into a temporary git
worktree, trains two iterations on synthetic data with this Python environment, and its
checkpoints are loaded by this checkout; no checkpoint is committed."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from src.eval import evaluate
from src.inference import MotionForecaster
from tests.conftest import ROOT, compose_config

COMMITS = ["58436ca", "4b904c1"]
# Overrides every one of these commits accepts: a tiny adversarial conv_s2s.
TINY = [
    "data=synthetic",
    "trainer=cpu",
    "trainer.enable_progress_bar=false",
    "model=conv_s2s",
    "model.net.nf=2",
    "model.net.d_z=8",
    "adversarial.discriminator.nf=2",
    "adversarial.discriminator.d_z=8",
    "adversarial.discriminator.d_fc=8",
    "data.batch_size=4",
    "iterations=2",
    "val_every=2",
]


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


@pytest.fixture
def checkpoints_of(tmp_path):
    """checkpoints_of(commit) -> (last.ckpt, best-*.ckpt) of a 2-iteration run at `commit`."""
    if shutil.which("git") is None:
        pytest.skip("git is not installed")

    def train_at(commit: str):
        if _git("rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}").returncode:
            pytest.skip(f"commit {commit} is not in this clone (a shallow clone or no .git)")
        tree = tmp_path / f"tree_{commit}"
        added = _git("worktree", "add", "--detach", str(tree), commit)
        assert added.returncode == 0, added.stderr
        try:
            env = {**os.environ, "MOTION_DATA_DIR": str(tmp_path / "data"), "OMP_NUM_THREADS": "1"}
            env.pop("PYTHONPATH", None)  # the commit's own src/, from its folder
            log_dir = tmp_path / f"logs_{commit}"
            proc = subprocess.run(
                [sys.executable, "-m", "src.train", *TINY, f"paths.log_dir={log_dir}"],
                cwd=tree,
                env=env,
                capture_output=True,
                text=True,
                timeout=600,
            )
        finally:
            _git("worktree", "remove", "--force", str(tree))
        assert proc.returncode == 0, proc.stderr[-3000:]
        (folder,) = log_dir.glob("train/runs/*/*/checkpoints")
        (best,) = folder.glob("best-*.ckpt")
        return folder / "last.ckpt", best

    return train_at


@pytest.mark.slow
@pytest.mark.parametrize("commit", COMMITS)
def test_a_checkpoint_of_an_earlier_commit_loads_in_eval_and_the_forecaster(
    commit, checkpoints_of, tmp_path, synthetic_data_dir
):
    for path in checkpoints_of(commit):
        saved = torch.load(path, map_location="cpu", weights_only=True)["state_dict"]
        forecaster = MotionForecaster.from_checkpoint(path)
        torch.testing.assert_close(
            forecaster.net.decoder[0].weight, saved["net.decoder.0.weight"], rtol=0, atol=0
        )
        future = forecaster.predict(np.zeros((50, 99), np.float32), future_len=5)
        assert future.shape == (5, 99) and np.isfinite(future).all()

        out = tmp_path / "eval" / path.stem
        result = evaluate(compose_config("eval", [f"ckpt_path={path}"], out, synthetic_data_dir))
        assert result["provenance"]["model"] == "conv_s2s"
        euler = result["tables"][0]
        assert euler["metric"] == "euler" and euler["values"], euler
        assert all(np.isfinite(v) for row in euler["values"].values() for v in row.values())
        assert (out / "results.json").is_file()
