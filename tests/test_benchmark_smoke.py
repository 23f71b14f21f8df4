"""benchmarks/benchmark.py --smoke runs end to end and writes the documented JSON keys."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_benchmark_smoke_writes_json(tmp_path):
    out, md = tmp_path / "bench.json", tmp_path / "perf.md"
    proc = subprocess.run(
        [
            sys.executable,
            "benchmarks/benchmark.py",
            "--smoke",
            "--json",
            str(out),
            "--markdown",
            str(md),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    r = json.loads(out.read_text())
    for key in (
        "context",
        "training_it_s",
        "train_flops",
        "inference",
        "matmul_gflops",
        "data",
        "validation_s",
        "validation_fraction",
        "targets",
        "command",
        "date",
    ):
        assert key in r, key
    assert {"commit", "cpu", "cores", "torch_threads", "device"} <= set(r["context"])
    kinds = ("conv_adv", "conv", "conv_recompute", "conv_shared_masks", "gru")
    assert set(r["training_it_s"]) == {f"{k}@2" for k in kinds}
    assert all(v > 0 for v in r["training_it_s"].values())
    inf = r["inference"]
    for key in (
        "latency_ms_median_inc",
        "latency_ms_p90_recompute",
        "throughput_seq_s_inc",
        "gflops_achieved_b1_inc",
    ):
        assert inf[key] > 0, key
    # incremental and recomputed predictions agree, and fewer FLOPs are counted for the former
    assert inf["max_abs_diff"] <= 1e-5
    assert inf["flops_per_prediction_inc"] < inf["flops_per_prediction_recompute"]
    assert "| target | measured | met |" in md.read_text()
