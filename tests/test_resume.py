"""Kill and resume: a run killed with SIGKILL between two epochs and resumed from its
last.ckpt ends bit for bit where an uninterrupted run of the same length ends (CPU, fixed seed),
with the adversarial regulariser on: both optimisers and LR schedulers, the eta schedule's
iteration counter, the training sampler's epoch and the torch random state all resume."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from tests.conftest import ROOT

# A tiny network so three subprocess runs fit in a slow test; the adversarial regulariser is on
# (model=conv_s2s defaults to adversarial=li2018).
TINY = [
    "data=synthetic",
    "model=conv_s2s",
    "trainer=cpu",
    "trainer.enable_progress_bar=false",
    "model.net.nf=2",
    "model.net.d_z=8",
    "adversarial.discriminator.nf=2",
    "adversarial.discriminator.d_z=8",
    "adversarial.discriminator.d_fc=8",
    "data.batch_size=4",
    "iterations=6",
    "val_every=2",
]


def _train_cmd(log_dir: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "src.train", f"paths.log_dir={log_dir}", *TINY, *extra]


def _env(data_dir: Path) -> dict[str, str]:
    # One thread: the same kernels in every run, and no oversubscription of a shared machine.
    return {**os.environ, "MOTION_DATA_DIR": str(data_dir), "OMP_NUM_THREADS": "1"}


def _run_folders(log_dir: Path) -> list[Path]:
    return sorted((log_dir / "train" / "runs").glob("*/*"))


def _kill_after_checkpoint(proc: subprocess.Popen, log_dir: Path, timeout: float = 400) -> dict:
    """Freeze `proc` as soon as its last.ckpt exists and loads, then SIGKILL it; return that
    checkpoint. SIGSTOP first, so the process cannot write on while the file is checked."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"run ended (rc {proc.returncode}) before it could be killed")
        found = list((log_dir / "train" / "runs").glob("*/*/checkpoints/last.ckpt"))
        if found:
            proc.send_signal(signal.SIGSTOP)
            try:
                ckpt = torch.load(found[0], map_location="cpu", weights_only=True)
            except Exception:  # caught mid-write: let it finish the file
                proc.send_signal(signal.SIGCONT)
                time.sleep(0.05)
                continue
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=60)
            return ckpt
        time.sleep(0.005)
    proc.kill()
    pytest.fail("no checkpoint appeared in time")


def _same(a, b, where: str = "") -> None:
    """Recursive bit-for-bit equality of checkpoint parts (tensors, dicts, lists, scalars)."""
    if isinstance(a, torch.Tensor):
        assert torch.equal(a, b), f"differs at {where}"
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), f"keys differ at {where}"
        for k in a:
            _same(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), f"length differs at {where}"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    else:
        assert a == b, f"differs at {where}: {a!r} != {b!r}"


@pytest.mark.slow
def test_killed_run_resumes_bit_for_bit(tmp_path, synthetic_data_dir):
    env = _env(synthetic_data_dir)

    # A: uninterrupted.
    log_a = tmp_path / "a"
    proc = subprocess.run(
        _train_cmd(log_a), cwd=ROOT, env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run_a,) = _run_folders(log_a)

    # B: killed after its first checkpoint (iteration 2 or, on a fast machine, 4).
    log_b = tmp_path / "b"
    killed = subprocess.Popen(
        _train_cmd(log_b),
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    saved = _kill_after_checkpoint(killed, log_b)
    assert killed.returncode == -signal.SIGKILL
    at = int(saved["state_dict"]["iteration"])
    assert at in (2, 4), f"killed at iteration {at}, not between epochs"
    (run_b,) = _run_folders(log_b)
    assert not (run_b / "summary.yaml").exists()
    last_b = run_b / "checkpoints" / "last.ckpt"
    before = last_b.read_bytes()

    # Resume B with the same command; Hydra gives it a new folder.
    time.sleep(1.1)  # run folders are timestamped to the second
    proc = subprocess.run(
        _train_cmd(log_b, f"ckpt_path={last_b}"),
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    folders = _run_folders(log_b)
    assert len(folders) == 2 and run_b in folders
    (resumed,) = [f for f in folders if f != run_b]
    assert last_b.read_bytes() == before, "resuming wrote into the killed run's folder"

    sum_a = OmegaConf.to_container(OmegaConf.load(run_a / "summary.yaml"))
    sum_b = OmegaConf.to_container(OmegaConf.load(resumed / "summary.yaml"))
    assert sum_b["iterations"] == sum_a["iterations"] == 6
    for key in ("final_val_euler_avg", "final_val_mpjpe_avg", "best_val_euler_avg"):
        assert sum_b[key] == sum_a[key], key  # exact: bit for bit on CPU

    end_a = torch.load(run_a / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    end_b = torch.load(resumed / "checkpoints" / "last.ckpt", weights_only=True)
    # Weights (generator, discriminator, iteration buffer), both optimisers' moments, both LR
    # schedulers and the random state: all identical.
    for part in ("state_dict", "optimizer_states", "lr_schedulers", "rng"):
        _same(end_a[part], end_b[part], part)
    assert len(end_a["optimizer_states"]) == 2 and len(end_a["lr_schedulers"]) == 2
    assert end_b["loops"]["fit_loop"]["epoch_progress"]["current"]["processed"] == 3
