"""Performance suite: training speed, inference latency/throughput, FLOP/s, data, eval cost.

    python benchmarks/benchmark.py [--device cpu|cuda] [--smoke] [--json out.json]
                                   [--markdown docs/performance.md] [--ref 58436ca]

Synthetic tensors of the real H3.6M shapes (D = 54 used of F = 99 columns, 50 -> 25 frames).
Training drives the real `MotionPredictor.training_step` through a minimal manual loop (the
Lightning hooks it calls are bound to plain PyTorch equivalents), so the losses, the
discriminator/generator alternation and the optimisers are the project's own. Every time is
the median over repeats, A/B variants interleaved so background load hits both alike.
--smoke runs each measurement a couple of times (CI, < 60 s); numbers are then meaningless.

Beside the bare loop it times `python -m src.train` itself (Trainer, callbacks, logging, data;
benchmarks/train_cli.py) for li2018_h36m and martinez2017_res_sup, and li2018_h36m at the
reference commit `--ref` side by side, and fills the speed targets table with what it measured
("not measured" for a device it did not run on). That part needs the real data (MOTION_ARCHIVES
or an unpacked MOTION_DATA_DIR) and is skipped by --smoke and --no-train-cli.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import sys
import time
from datetime import datetime, timezone
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402
from torch.utils.flop_counter import FlopCounterMode  # noqa: E402

from benchmarks.benchmark_page import (  # noqa: E402
    TRAIN_KINDS,
    issue_targets,
    markdown,
    write_page,
)
from benchmarks.data_loading import machine_info  # noqa: E402
from src.data.normalization import Normalizer  # noqa: E402
from src.inference import compile_for_prediction  # noqa: E402
from src.lit.predictor import MotionPredictor  # noqa: E402
from src.models.conv_s2s import ConvSeq2Seq  # noqa: E402

F_RAW, D, A, OBS, FUT = 99, 54, 15, 50, 25
VAL_WINDOWS = 8 * A  # protocol: 8 test windows per action


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def timed(fn, device, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        sync(device)
        t0 = time.perf_counter()
        fn()
        sync(device)
        out.append(time.perf_counter() - t0)
    return out


def p90(xs: list[float]) -> float:
    return sorted(xs)[min(len(xs) - 1, int(round(0.9 * (len(xs) - 1))))]


# ---------------------------------------------------------------------------- models
def conv_net(**kw) -> ConvSeq2Seq:
    return ConvSeq2Seq(D, A, **kw)


def module(kind: str, device: torch.device) -> MotionPredictor:
    """A MotionPredictor as the configs build it (li2018 / martinez2017 hyper-parameters)."""
    normalizer = Normalizer(torch.zeros(F_RAW), torch.ones(F_RAW), torch.arange(F_RAW) < D)
    adam = {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 5e-5, "fused": True}
    if kind.startswith("conv"):
        net, opt, lambda_2, clip = "src.models.conv_s2s.ConvSeq2Seq", adam, 1e-3, None
    else:
        net, lambda_2, clip = "src.models.gru_s2s.GRUSeq2Seq", 0.0, 5.0
        opt = {"_target_": "torch.optim.SGD", "_partial_": True, "lr": 5e-3}
    adversarial = {
        "enabled": True,
        "discriminator": {"_target_": "src.models.discriminator.Discriminator"},
        "optimizer": adam,
        "lambda_adv": 0.01,
        "lambda_2": 1e-3,
    }
    m = MotionPredictor(
        model={"net": {"_target_": net}, "optimizer": opt, "lambda_2": lambda_2,
               "grad_clip_norm": clip, "lr_decay_every": 10000, "lr_decay_gamma": 1.0},
        data={"dataset": "h36m", "actions": [f"a{i}" for i in range(A)], "observed_len": OBS,
              "future_len": FUT, "frame_ms": 40.0, "conv_padding": "same",
              "used": list(range(D)), "num_features": F_RAW},
        sampling={"_target_": "src.lit.eta_schedule.Constant", "eta": 0.9},  # eq. (10) mixing
        adversarial=adversarial if kind == "conv_adv" else None,
        normalizer=normalizer,
    ).to(device)  # fmt: skip
    # Bind the Lightning hooks training_step calls to plain PyTorch: no Trainer needed.
    opts, scheds = m.configure_optimizers()
    m.optimizers = lambda: opts if len(opts) > 1 else opts[0]  # as Lightning returns them
    m.lr_schedulers = lambda: scheds
    params = [p for o in opts for g in o.param_groups for p in g["params"]]

    def toggle(opt):  # as Lightning's: the other optimisers' parameters get no gradients
        own = {id(p) for g in opt.param_groups for p in g["params"]}
        for p in params:
            p.requires_grad_(id(p) in own)

    m.toggle_optimizer = toggle
    m.untoggle_optimizer = lambda opt: [p.requires_grad_(True) for p in params]
    m.manual_backward = lambda loss: loss.backward()
    m.clip_gradients = lambda opt, gradient_clip_val, gradient_clip_algorithm: (
        torch.nn.utils.clip_grad_norm_(m.net.parameters(), gradient_clip_val)
    )
    m.log = m.log_dict = lambda *a, **k: None
    return m.train()


def batch(B: int, device, adversarial: bool) -> dict:
    windows = {
        "observed": torch.randn(B, OBS, D, device=device),
        "future": torch.randn(B, FUT, D, device=device),
        "action": torch.randint(0, A, (B,), device=device),
    }
    # With the regulariser the datamodule adds D's own windows (protocol §6.6).
    return {**windows, "d": batch(B, device, False)} if adversarial else windows


def bench_training(device, batches, repeats) -> tuple[dict, dict, dict]:
    """Iterations/s per (kind, batch), interleaving kinds per repeat; plus FLOPs/iteration and
    whether each kind's step ran compiled."""
    times: dict[str, list[float]] = {}
    flops: dict[str, float] = {}
    compiled: dict[str, bool] = {}
    for B in batches:
        mods = {k: module(k, device) for k in TRAIN_KINDS}
        data = {k: batch(B, device, k == "conv_adv") for k in TRAIN_KINDS}
        for k, m in mods.items():
            # The FLOPs of one iteration, counted on the eager step (every op visible) ...
            m.compile_step, m._compiled = False, None
            with FlopCounterMode(display=False) as fc:
                m.training_step(data[k], 0)
            flops[f"{k}@{B}"] = fc.get_total_flops()
            # ... then as src.train runs it by default (compile.enabled=false: eager on every
            # device; bench_compile times the compiled step), warmed up.
            m.compile_step, m._compiled = False, None
            for _ in range(3):
                m.training_step(data[k], 0)
            compiled[k] = m._objectives()[0]
        for _ in range(repeats):
            for k, m in mods.items():
                step = partial(m.training_step, data[k], 0)
                times.setdefault(f"{k}@{B}", []).extend(timed(step, device, 1))
    return {k: statistics.median(v) for k, v in times.items()}, flops, compiled


def bench_compile(device, B: int, repeats: int) -> dict:
    """it/s of the conv_s2s + adversarial step eager and compiled (compile.enabled=false/true),
    interleaved: the measurement a choice of compile.enabled's default needs per device."""
    data = batch(B, device, True)
    mods = {flag: module("conv_adv", device) for flag in (False, True)}
    times: dict[bool, list[float]] = {}
    start = time.perf_counter()
    for flag, m in mods.items():
        m.compile_step = flag
        for _ in range(3):  # compiling and recording CUDA graphs take the first calls
            m.training_step(data, 0)
    warm_s = time.perf_counter() - start
    for _ in range(repeats):
        for flag, m in mods.items():
            times.setdefault(flag, []).extend(timed(partial(m.training_step, data, 0), device, 1))
    its = {flag: 1.0 / statistics.median(v) for flag, v in times.items()}
    return {"batch": B, "eager": its[False], "compiled": its[True], "warm_up_s": warm_s}


def bench_compiled_prediction(device, repeats: int) -> dict:
    """Batch-1 latency of forward() eager and compiled as MotionForecaster(compile=True) runs
    it (on CUDA: one CUDA graph per shape), interleaved."""
    net = conv_net().to(device).eval()
    paths = {False: net, True: compile_for_prediction(net)}
    x1 = torch.randn(1, OBS, D, device=device)
    times: dict[bool, list[float]] = {}
    with torch.inference_mode():
        start = time.perf_counter()
        for _ in range(3):  # compiling and recording take the first calls
            paths[True](x1, FUT)
        warm_s = time.perf_counter() - start
        diff = (paths[True](x1, FUT) - paths[False](x1, FUT)).abs().max().item()
        for _ in range(repeats):
            for flag, f in paths.items():
                times.setdefault(flag, []).extend(timed(partial(f, x1, FUT), device, 1))
    ms = {flag: 1e3 * statistics.median(v) for flag, v in times.items()}
    return {"eager_ms": ms[False], "compiled_ms": ms[True], "warm_up_s": warm_s, "max_diff": diff}


def bench_inference(device, repeats, big: int) -> dict:
    """Prediction of 25 frames from 50 (every short-term window encoded anew, eq. 4): latency
    at batch 1, throughput at batch `big`, FLOPs and the FLOP rate at batch 1."""
    net = conv_net().to(device).eval()
    x1 = torch.randn(1, OBS, D, device=device)
    xb = torch.randn(big, OBS, D, device=device)
    with torch.inference_mode():
        net(x1, FUT)  # warm-up
        lat = timed(partial(net, x1, FUT), device, repeats)
        big_s = statistics.median(timed(partial(net, xb, FUT), device, max(2, repeats // 10)))
        with FlopCounterMode(display=False) as fc:
            net(x1, FUT)
    flops = fc.get_total_flops()
    return {
        "latency_ms_median": 1e3 * statistics.median(lat),
        "latency_ms_p90": 1e3 * p90(lat),
        "throughput_seq_s": big / big_s,
        "throughput_batch": big,
        "flops_per_prediction": flops,
        "gflops_achieved_b1": flops / statistics.median(lat) / 1e9,
    }


# Operators that do a step's arithmetic: convolutions (forward and backward) and matrix
# products. Everything else (dropout draws, padding copies, element-wise ops, the
# optimiser, Python) is what an implementation could still remove.
ARITHMETIC = re.compile(r"conv|(^|::)(add)?b?mm$")


def bench_profile(device, B: int, steps: int, top: int = 8) -> tuple[list[list], dict]:
    """Where a conv_s2s + adversarial training step spends its time: the operators with the
    most self time (torch.profiler), as [name, share of the step, calls per step]; and the
    ARITHMETIC operators' share and seconds per step."""
    from torch.profiler import ProfilerActivity, profile

    m, data = module("conv_adv", device), batch(B, device, True)
    m.training_step(data, 0)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with profile(activities=activities) as prof:
        for _ in range(steps):
            m.training_step(data, 0)
        sync(device)
    key = "self_device_time_total" if device.type == "cuda" else "self_cpu_time_total"
    events = [e for e in prof.key_averages() if getattr(e, key) > 0]
    total = sum(getattr(e, key) for e in events)
    events.sort(key=lambda e: getattr(e, key), reverse=True)
    arithmetic_us = sum(getattr(e, key) for e in events if ARITHMETIC.search(e.key))
    rows = [[e.key, getattr(e, key) / total, e.count / steps] for e in events[:top]]
    return rows, {"share": arithmetic_us / total, "s_per_it": arithmetic_us / steps / 1e6}


def bench_matmul(device, n: int, repeats: int) -> float:
    a, b = torch.randn(n, n, device=device), torch.randn(n, n, device=device)
    a @ b
    return 2 * n**3 / statistics.median(timed(lambda: a @ b, device, repeats)) / 1e9


def bench_validation(device, repeats) -> float:
    """One validation pass: the 8-window protocol (120 windows), predict + metrics."""
    m = module("conv_adv", device).eval()
    b = {
        "observed": torch.randn(VAL_WINDOWS, OBS, D, device=device),
        "future": torch.randn(VAL_WINDOWS, FUT, D, device=device),
        "action": torch.arange(VAL_WINDOWS, device=device) % A,
    }

    def run():
        with torch.inference_mode():
            m.validation_step(b, 0)
            m.euler.compute(), m.mpjpe.compute()
            m.euler.reset(), m.mpjpe.reset()

    return statistics.median(timed(run, device, repeats))


def bench_data(batches: int) -> dict:
    """Cached load of the real H3.6M arrays and train-window sampling, when data is present."""
    data_dir = os.environ.get("MOTION_DATA_DIR")
    if not data_dir or not (Path(data_dir) / "h3.6m").is_dir():
        return {"note": "skipped: set MOTION_DATA_DIR to an unpacked data_dir (h3.6m/)"}
    from src.data.h36m import H36MDataModule

    try:
        dm = H36MDataModule(Path(data_dir), allow_partial=True, batch_size=16)
        t0 = time.perf_counter()
        dm.setup("fit")
        setup_s = time.perf_counter() - t0
        it = iter(dm.train_dataloader())
        next(it)
        t0 = time.perf_counter()
        for _ in range(batches):
            next(it)
        dt = time.perf_counter() - t0
        return {
            "cached_setup_s": setup_s,
            "windows_per_s": batches * dm.batch_size / dt,
            "note": f"H3.6M in {data_dir}, allow_partial, batch 16",
        }
    except Exception as err:  # report, do not fail the suite
        return {"note": f"skipped: {type(err).__name__}: {err}"}


def bench_train_cli(device: torch.device, ref: str, iterations: int) -> dict:
    """it/s of `python -m src.train` itself: li2018_h36m here and at `ref`, side by side, and
    martinez2017_res_sup here (benchmarks/train_cli.py: two run lengths, start-up cancels)."""
    from benchmarks.train_cli import measure

    trainer = "gpu" if device.type == "cuda" else "cpu"
    threads = torch.get_num_threads()
    # Best of 2: single runs of this length varied by 10% on a shared VM.
    short = iterations // 3
    conv = measure(ref, "li2018_h36m", trainer, iterations, short, threads, repeats=2)
    gru = measure(None, "martinez2017_res_sup", trainer, iterations, short, threads, repeats=2)
    return {
        "device": trainer,
        "iterations": iterations,
        "ref": ref,
        "conv_adv": conv["this checkout"],
        "conv_adv_ref": conv.get(f"commit {ref}"),
        "gru": gru["this checkout"],
    }


def arithmetic_bound(arithmetic: dict, cli: dict) -> dict:
    """The fastest a conv_s2s + adversarial iteration could run if everything but its
    convolutions and matrix products (at this run's speed of those kernels) took no time."""
    out = {**arithmetic, "its": 1.0 / arithmetic["s_per_it"]}
    if cli.get("conv_adv_ref"):
        out["x_ref"] = out["its"] / cli["conv_adv_ref"]
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--smoke", action="store_true", help="tiny run for CI (< 60 s)")
    ap.add_argument("--json", type=Path, default=ROOT / "outputs" / "benchmark.json")
    ap.add_argument(
        "--markdown",
        type=Path,
        help="also write the report to this page, between its <!-- benchmark:start/end --> "
        "markers when it has them (docs/performance.md), else as a new file",
    )
    ap.add_argument("--val-every", type=int, default=1000, help="conf/train.yaml val_every")
    ap.add_argument("--ref", default="58436ca", help="commit src.train is compared with")
    ap.add_argument("--cli-iterations", type=int, default=60, help="src.train run length")
    ap.add_argument("--no-train-cli", action="store_true", help="skip timing src.train")
    args = ap.parse_args(argv)
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit("--device cuda: CUDA is not available on this machine")
    torch.manual_seed(0)

    smoke = args.smoke
    batches = [2] if smoke else [16, 64]
    context = {**machine_info(), "torch_threads": torch.get_num_threads(), "device": str(device)}
    if device.type == "cuda":
        context["device"] = torch.cuda.get_device_name(device)
    train, flops, compiled = bench_training(device, batches, 1 if smoke else 5)
    inference = bench_inference(device, 2 if smoke else 30, 4 if smoke else 256)
    n = 256 if smoke else 2048
    matmul = bench_matmul(device, n, 2 if smoke else 10)
    val_s = bench_validation(device, 1 if smoke else 5)
    B0 = batches[0]
    train_its = {k: 1.0 / v for k, v in train.items()}
    val_frac = val_s / (args.val_every / train_its[f"conv_adv@{B0}"])
    lat = inference["latency_ms_median"]
    # Compiling takes a minute on the CPU: not in the CI smoke run.
    pred = {} if smoke else bench_compiled_prediction(device, 30)
    profile, arithmetic = bench_profile(device, B0, 1 if smoke else 5)
    cli = {}
    if not (smoke or args.no_train_cli):
        cli = bench_train_cli(device, args.ref, args.cli_iterations)
    bound = arithmetic_bound(arithmetic, cli)
    r = {
        "command": "python benchmarks/benchmark.py "
        + " ".join(sys.argv[1:] if argv is None else argv),
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "smoke": smoke,
        "context": context,
        "batches": batches,
        "training_it_s": train_its,
        "train_flops": flops,
        "train_compiled": compiled,
        "inference": inference,
        "matmul_n": n,
        "matmul_gflops": matmul,
        "data": bench_data(3 if smoke else 200),
        "validation_s": val_s,
        "profile": profile,
        # Compiling takes minutes on the CPU: not in the CI smoke run.
        "compile": {} if smoke else bench_compile(device, batches[0], 5),
        "compiled_prediction": pred,
        "val_every": args.val_every,
        "validation_fraction": val_frac,
        "train_cli": cli,
        "arithmetic_bound": bound,
        "issue_targets": issue_targets(device, cli, inference, pred, bound),
        "targets": {
            "latency batch 1 <= 10 ms (median)": (f"{lat:.1f} ms", lat <= 10),
        },
    }
    table = markdown(r)
    print(table)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(r, indent=1))
    if args.markdown:
        write_page(args.markdown, table)
    return r


if __name__ == "__main__":
    main()
