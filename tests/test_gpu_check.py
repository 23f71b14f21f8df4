"""benchmarks/gpu_check.py, the first command to run on a GPU: it runs on the CPU, says there is
no CUDA device, and its GPU-only parts (which no machine of this project has run yet) produce
the page they are meant to from results of the shape they return."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from collections import Counter

import pytest
import torch

from tests.conftest import ROOT

sys.path.insert(0, str(ROOT))
from benchmarks import gpu_check  # noqa: E402

SECTIONS = (
    "## Summary",
    "## CUDA tests",
    "## Eager and compiled training step: objectives (8) and (9), TF32 off",
    "## Training through `src.train`",
    "## Prediction latency, batch 1",
    "## Host syncs per training iteration",
)


@pytest.mark.skipif(torch.cuda.is_available(), reason="on a GPU the check itself is the test")
def test_on_the_cpu_it_says_there_is_no_cuda_device_and_checks_what_it_can(
    tmp_path, synthetic_data_dir
):
    page = tmp_path / "page.md"
    proc = subprocess.run(
        [sys.executable, "benchmarks/gpu_check.py", "--out", str(page), "--iterations", "2"],
        cwd=ROOT,
        env={**os.environ, "MOTION_DATA_DIR": str(synthetic_data_dir)},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert proc.stdout.startswith("NO CUDA DEVICE")
    text = page.read_text()
    assert text.startswith("# GPU check\n\n**No CUDA device**")
    for section in SECTIONS:
        assert section in text, section
    assert "Data: synthetic (`data=synthetic`: no --archives given)" in text
    # The eager trainings ran: two iterations each, a rate and a time to the first step.
    for exp in gpu_check.EXPERIMENTS:
        (row,) = [x for x in text.splitlines() if x.startswith(f"| {exp}, eager |")]
        cells = [c.strip() for c in row.split("|")[1:-1]]
        assert cells[1] == "2" and cells[-1] == "ok", row
        assert float(cells[2]) > 0 and float(cells[3]) > 0, row
        assert f"| {exp}, compiled | 0 |" in text
    assert "median of 10 calls: eager " in text and "compiled: not measured" in text
    assert "Steps that failed: none." in text


def test_the_cuda_page_from_results_of_the_shape_a_gpu_run_returns():
    equality = f"tests/test_compile.py::{gpu_check.EQUALITY_TEST}[cuda-gru_s2s]"
    r = {
        "command": "python benchmarks/gpu_check.py",
        "date": "today",
        "cuda": True,
        "device_name": "NVIDIA H100",
        "context": {"commit": "abc", "torch": "2.13.0+cu130", "cpu": "Xeon", "cores": 16},
        "data": "the archives",
        "data_s": 3.0,
        "skipped": [],
        "failed": [],
        "latency_repeats": 30,
        "train_overrides": ["trainer=gpu", "iterations=300"],
        "syncs": {"window": 20, "per_iteration": 1.1, "sites": Counter({"src/a.py:3": 22})},
        "latency": {"eager_ms": 15.0, "compiled_ms": 2.0, "warm_up_s": 40.0, "max_diff": 1e-6},
        "tests": {
            "status": "exit 0",
            "cases": [
                (equality, "passed", 9.0, ""),
                ("tests/test_inference.py::test_x[cuda]", "failed", 2.0, "assert 1 == 2"),
            ],
        },
        "train": [
            {"label": "li2018_h36m, eager", "status": "ok", "its": 5.0, "first_step_s": 20.0,
             "wall_s": 80.0, "iterations_done": 300},
            {"label": "li2018_h36m, compiled", "status": "ok", "its": 20.0, "first_step_s": 200.0,
             "wall_s": 230.0, "iterations_done": 300},
            {"label": "martinez2017_res_sup, eager", "status": "ok", "its": 12.0,
             "first_step_s": 15.0, "wall_s": 40.0, "iterations_done": 300},
            {"label": "martinez2017_res_sup, compiled", "status": "skipped (time budget)"},
        ],
    }  # fmt: skip
    text = gpu_check.render(r)
    assert "No CUDA device" not in text
    for section in SECTIONS:
        assert section in text, section
    assert "- li2018_h36m: eager 5.00 it/s, compiled 20.00 it/s (4.00x);" in text
    assert "- martinez2017_res_sup: eager 12.00 it/s, compiled: skipped (time budget);" in text
    assert "- host syncs per training iteration: 1.1;" in text
    assert "- CUDA tests: 1 failed, 1 passed." in text
    assert f"- `{gpu_check.EQUALITY_TEST}[cuda-gru_s2s]`: passed" in text
    assert "| `src/a.py:3` | 1.10 |" in text
    assert "compiled (`compile_for_prediction`) 2.0 ms" in text


def test_steady_rate_leaves_out_the_first_tenth_and_dates_the_first_step():
    # Compiling: iteration 1 ends at 100 s; then 10 it/s, with a slow tenth at the start.
    points = [(1, 100.0), (5, 102.0), (40, 104.0)] + [(i, 100 + i / 10) for i in (60, 100)]
    speed = gpu_check._speed(points)
    assert speed["its"] == pytest.approx(10.0)  # from iterations 40 to 100 only
    assert speed["first_step_s"] == pytest.approx(100.0) and speed["iterations_done"] == 100
    # Eager: the first line at iteration 5 is dated back to iteration 1 at the steady rate.
    speed = gpu_check._speed([(i, 10 + i / 5) for i in (5, 20, 40, 60)])
    assert speed["its"] == pytest.approx(5.0) and speed["first_step_s"] == pytest.approx(10.2)
    assert gpu_check._speed([])["its"] is None


def test_test_outcomes_are_read_from_junit_xml(tmp_path):
    xml = tmp_path / "r.xml"
    xml.write_text(
        '<testsuites><testsuite name="pytest">'
        '<testcase classname="tests.test_compile" name="test_a[cuda-gru_s2s]" time="3.5"/>'
        '<testcase classname="tests.test_compile" name="test_b" time="0.1">'
        '<failure message="AssertionError: 1 | 2&#10;more">trace</failure></testcase>'
        '<testcase classname="tests.test_inference" name="test_c[cuda]" time="0">'
        '<skipped message="needs CUDA" /></testcase>'
        "</testsuite></testsuites>"
    )
    assert gpu_check.junit_cases(xml) == [
        ("tests/test_compile.py::test_a[cuda-gru_s2s]", "passed", 3.5, ""),
        ("tests/test_compile.py::test_b", "failed", 0.1, "AssertionError: 1 / 2"),
        ("tests/test_inference.py::test_c[cuda]", "skipped", 0.0, "needs CUDA"),
    ]


def test_host_syncs_are_counted_per_iteration_in_the_window_by_call_site(
    tmp_path, synthetic_data_dir, monkeypatch
):
    """The window (iterations skip+1 .. skip+window) and the attribution, on the CPU: a stand-in
    for torch's sync debug mode warns once per training step while it is on."""
    from src.lit.predictor import MotionPredictor

    mode = {"now": 0}
    monkeypatch.setattr(torch.cuda, "set_sync_debug_mode", lambda m: mode.update(now=m))
    step = MotionPredictor.training_step

    def training_step(self, batch, batch_idx):
        if mode["now"] == "warn":
            warnings.warn("called a synchronizing CUDA operation", stacklevel=1)
        return step(self, batch, batch_idx)

    monkeypatch.setattr(MotionPredictor, "training_step", training_step)
    tiny = ("trainer=cpu", "model.net.nf=2", "model.net.d_z=8", "+model.net.d_dec=8")
    counted = gpu_check.count_host_syncs(synthetic_data_dir, tmp_path, tiny, skip=2, window=3)
    line = training_step.__code__.co_firstlineno + 2
    assert counted["per_iteration"] == 1.0
    assert counted["sites"] == Counter({f"tests/test_gpu_check.py:{line}": 3})
    assert mode["now"] == 0 and "on_train_batch_start" not in vars(MotionPredictor)
