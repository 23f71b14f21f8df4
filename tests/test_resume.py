"""Kill and resume: a run killed with SIGKILL and resumed from its last.ckpt continues in its
own folder and ends bit for bit where an uninterrupted run of the same length ends (CPU, fixed
seed), with the adversarial regulariser on: both optimisers and LR schedulers, the eta
schedule's iteration counter, the training sampler's position and the torch random state."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from src.reporting.runs import validation_curve
from tests.conftest import ROOT
from tests.objects import TINY_CONV

# A tiny network so three subprocess runs fit in a slow test; the adversarial regulariser is on
# (model=conv_s2s defaults to adversarial=li2018).
TINY = [
    "data=synthetic",
    "trainer=cpu",
    "trainer.enable_progress_bar=false",
    *TINY_CONV,
    "iterations=6",
    "val_every=2",
]


def _train_cmd(log_dir: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "src.train", f"paths.log_dir={log_dir}", *TINY, *extra]


RISING_ERROR = """
# Test hook loaded through PYTHONPATH: the validation error only rises (1 per iteration), so
# every validation after the first is no improvement, the case that used to leave an old
# last.ckpt behind (Lightning wrote it only together with a new best).
from src.lit.predictor import MotionPredictor

_log_dict = MotionPredictor.log_dict


def _rising(self, metrics, **kwargs):
    if "val/euler_avg" in metrics:
        metrics = {**metrics, "val/euler_avg": float(self.global_step)}
    return _log_dict(self, metrics, **kwargs)


MotionPredictor.log_dict = _rising
"""


def _env(data_dir: Path, hook_dir: Path | None = None) -> dict[str, str]:
    # One thread: the same kernels in every run, and no oversubscription of a shared machine.
    env = {**os.environ, "MOTION_DATA_DIR": str(data_dir), "OMP_NUM_THREADS": "1"}
    if hook_dir is not None:
        hook_dir.mkdir(exist_ok=True)
        (hook_dir / "sitecustomize.py").write_text(RISING_ERROR)
        env["PYTHONPATH"] = os.pathsep.join([str(hook_dir), str(ROOT)])
    return env


def _run_folders(log_dir: Path) -> list[Path]:
    return sorted((log_dir / "train" / "runs").glob("*/*"))


def _kill_after_checkpoint(
    proc: subprocess.Popen, log_dir: Path, at: int, timeout: float = 400
) -> dict:
    """Freeze `proc` as soon as its last.ckpt holds iteration `at`, then SIGKILL it; return that
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
            if ckpt["global_step"] < at:
                proc.send_signal(signal.SIGCONT)
                time.sleep(0.005)
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
    """Killed right after the validation of iteration 4, which did not improve on iteration
    2's: last.ckpt must hold iteration 4 all the same. eta ramps over the run (a constant
    eta would hide a schedule that restarts at the resume)."""
    env = _env(synthetic_data_dir, tmp_path / "hook")
    ramp = "sampling=linear"  # eta 0 -> 1 over the run's 6 iterations

    # A: uninterrupted.
    log_a = tmp_path / "a"
    proc = subprocess.run(
        _train_cmd(log_a, ramp), cwd=ROOT, env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run_a,) = _run_folders(log_a)

    assert sorted(p.name for p in (run_a / "checkpoints").glob("best-*")) == [
        "best-iter000002.ckpt"
    ], "the hook should make every later validation worse"

    # B: killed after the checkpoint of its second validation (no improvement).
    log_b = tmp_path / "b"
    killed = subprocess.Popen(
        _train_cmd(log_b, ramp),
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    saved = _kill_after_checkpoint(killed, log_b, at=4)
    assert killed.returncode == -signal.SIGKILL
    at = saved["global_step"]
    assert at == 4, f"killed at iteration {at}, not after the second validation"
    (run_b,) = _run_folders(log_b)
    assert not (run_b / "summary.yaml").exists()
    last_b = run_b / "checkpoints" / "last.ckpt"
    overrides = (run_b / ".hydra" / "overrides.yaml").read_text()

    # Resume B with the same command: it continues in its own folder.
    time.sleep(1.1)  # run folders are timestamped to the second
    proc = subprocess.run(
        _train_cmd(log_b, ramp, f"ckpt_path={last_b}"),
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert _run_folders(log_b) == [run_b]
    resumed = run_b
    # Hydra's record of the run is kept; the resume's is beside it.
    assert (run_b / ".hydra" / "overrides.yaml").read_text() == overrides
    (record,) = (run_b / ".hydra").glob("resumed-*/overrides.yaml")
    assert f"ckpt_path={last_b}" in record.read_text()

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
    # Killed after iteration 4's validation: the resumed run neither repeats nor skips one,
    # and its log and TensorBoard curves continue the killed run's.
    log = (resumed / "train.log").read_text()
    assert re.findall(r"validation at iteration (\d+)", log) == ["2", "4", "6"], log[-3000:]
    assert validation_curve(resumed) == validation_curve(run_a) != {}


SIGTERM_DURING_ITERATION = """
# Test hook loaded through PYTHONPATH: SIGTERM (a cluster's pre-emption) arrives while
# iteration SIGTERM_IN runs, always at the same point.
import os
import signal

from src.lit.predictor import MotionPredictor

_step = MotionPredictor.training_step


def _step_with_sigterm(self, batch, batch_idx):
    if self.global_step + 1 == int(os.environ["SIGTERM_IN"]):
        os.kill(os.getpid(), signal.SIGTERM)
    return _step(self, batch, batch_idx)


MotionPredictor.training_step = _step_with_sigterm
"""


@pytest.mark.parametrize("iteration", [3, 4], ids=["between_validations", "at_a_validation"])
def test_sigterm_saves_and_exits_143(tmp_path, synthetic_data_dir, iteration):
    """SIGTERM takes the Ctrl-C path, not Lightning's own SIGTERM handling: the iteration in
    progress finishes (and its validation, where one is due, so that the resume does not skip
    it), last.ckpt holds it, the resume command is printed, exit status 143."""
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(SIGTERM_DURING_ITERATION)
    env = {**_env(synthetic_data_dir), "PYTHONPATH": os.pathsep.join([str(hook), str(ROOT)])}
    env["SIGTERM_IN"] = str(iteration)
    log_dir = tmp_path / "logs"
    proc = subprocess.run(
        _train_cmd(log_dir, "checkpoint_every=0"),  # TINY: 6 iterations, validation every 2
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 128 + signal.SIGTERM, out[-3000:]
    assert "Traceback" not in out, out[-3000:]
    (run,) = _run_folders(log_dir)
    last = run / "checkpoints" / "last.ckpt"
    assert f"SIGTERM received: stopped after iteration {iteration} and wrote {last}" in out, out
    assert f"ckpt_path={last}" in out
    assert torch.load(last, weights_only=True)["global_step"] == iteration
    assert not (run / "summary.yaml").exists()
    validated = re.findall(r"validation at iteration (\d+)", (run / "train.log").read_text())
    assert validated == [str(n) for n in range(2, iteration + 1, 2)]


@pytest.mark.slow
def test_ctrl_c_between_validations_saves_and_resumes_exactly(tmp_path, synthetic_data_dir):
    """SIGINT mid-epoch: the iteration in progress finishes, last.ckpt is written and named,
    the process exits without a traceback, and the resumed run ends where an uninterrupted
    one does (the training sampler skips the batches the epoch already used)."""
    env = {**_env(synthetic_data_dir), "PYTHONUNBUFFERED": "1"}
    n = ["iterations=300", "val_every=300", "checkpoint_every=0"]

    log_a = tmp_path / "a"
    proc = subprocess.run(
        _train_cmd(log_a, *n), cwd=ROOT, env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run_a,) = _run_folders(log_a)

    log_b = tmp_path / "b"
    proc = subprocess.Popen(
        _train_cmd(log_b, *n),
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    seen = []
    for line in proc.stdout:  # the model summary is printed when fit starts
        seen.append(line)
        if "Trainable params" in line:
            break
    time.sleep(2.0)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    proc.send_signal(signal.SIGINT)
    out = "".join(seen) + proc.stdout.read()
    assert proc.wait(timeout=120) == 130, out[-3000:]
    assert "Traceback" not in out, out[-3000:]
    (run_b,) = _run_folders(log_b)
    last_b = run_b / "checkpoints" / "last.ckpt"
    assert f"wrote {last_b}" in out and f"ckpt_path={last_b}" in out
    at = torch.load(last_b, weights_only=True)["global_step"]
    assert 0 < at < 300, f"interrupted at iteration {at}, not between validations"
    assert not (run_b / "summary.yaml").exists()

    time.sleep(1.1)
    proc = subprocess.run(
        _train_cmd(log_b, *n, f"ckpt_path={last_b}"),
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert _run_folders(log_b) == [run_b]  # continued in its own folder
    end_a = torch.load(run_a / "checkpoints" / "last.ckpt", weights_only=True)
    end_b = torch.load(last_b, weights_only=True)
    for part in ("state_dict", "optimizer_states", "lr_schedulers", "rng"):
        _same(end_a[part], end_b[part], part)
