"""Time one conv_s2s + adversarial training step (batch 16) with torch's nn.Dropout and with
src.models.dropout.Dropout, interleaved, on the CPU: the gain that module is kept for.

    python benchmarks/dropout.py [--repeats 8] [--threads 1]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402
from torch import nn  # noqa: E402

from benchmarks.benchmark import batch, module  # noqa: E402
from src.models.dropout import Dropout  # noqa: E402


def main(argv: list[str] | None = None) -> dict[str, float]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=8)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cpu = torch.device("cpu")
    m, data = module("conv_adv", cpu), batch(16, cpu, True)
    m.training_step(data, 0)  # warm-up
    variants = {"nn.Dropout (bernoulli_)": nn.Dropout.forward, "Dropout (uniform)": Dropout.forward}
    seconds: dict[str, list[float]] = {name: [] for name in variants}
    try:
        for _ in range(args.repeats):
            for name, forward in variants.items():  # alternating: load hits both alike
                Dropout.forward = forward
                start = time.perf_counter()
                m.training_step(data, 0)
                seconds[name].append(time.perf_counter() - start)
    finally:
        Dropout.forward = variants["Dropout (uniform)"]
    medians = {name: statistics.median(s) for name, s in seconds.items()}
    for name, s in medians.items():
        print(f"{name}: {s:.3f} s per step (median of {args.repeats})")
    old, new = medians.values()
    print(f"speed-up of Dropout over nn.Dropout: {old / new:.2f}x ({args.threads} thread(s))")
    return medians


if __name__ == "__main__":
    main()
