"""The page of benchmarks/benchmark.py: its table, the speed targets and notes
(docs/performance.md), all generated from one result dict."""

from __future__ import annotations

from pathlib import Path

import torch

TRAIN_KINDS = {
    "conv_adv": "conv_s2s + adversarial (default config)",
    "conv": "conv_s2s, no adversarial",
    "gru": "gru_s2s (Martinez residual sup.)",
}


def issue_targets(
    device: torch.device, cli: dict, inference: dict, pred: dict, bound: dict | None = None
) -> list[list[str]]:
    """Rows [measurement, now, target] of the speed targets table, from this run only."""
    on_gpu = device.type == "cuda"
    here = "GPU" if on_gpu else "CPU"
    absent = f"not measured (this run was on the {here})"
    skipped = "not measured (src.train timing skipped)"

    def its(key: str, gpu_row: bool) -> str:
        if gpu_row != on_gpu:
            return absent
        return f"{cli[key]:.2f} it/s" if cli else skipped

    cpu_ratio = skipped
    if cli and not on_gpu and cli.get("conv_adv_ref"):
        cpu_ratio = (
            f"{cli['conv_adv']:.2f} it/s, {cli['conv_adv'] / cli['conv_adv_ref']:.2f}x commit "
            f"{cli['ref']} ({cli['conv_adv_ref']:.2f} it/s) side by side"
        )
        if bound and "x_ref" in bound:
            cpu_ratio += (
                f"; at most {bound['x_ref']:.2f}x with everything but the step's convolutions "
                "and matrix products free"
            )
    elif on_gpu:
        cpu_ratio = absent
    lat = f"{inference['latency_ms_median']:.1f} ms {here}"
    if pred:
        lat += f", {pred['compiled_ms']:.1f} ms (compiled)"
    return [
        ["conv_s2s + regulariser, batch 16, `src.train`, GPU", its("conv_adv", True), ">= 35 it/s"],
        ["gru_s2s, batch 16, `src.train`, GPU", its("gru", True), ">= 100 it/s"],
        ["conv_s2s + regulariser, batch 16, `src.train`, CPU", cpu_ratio, ">= 2x commit 58436ca"],
        ["gru_s2s, batch 16, `src.train`, CPU", its("gru", False), "-"],
        ["prediction, batch 1, 25 frames", lat, "<= 10 ms CPU, <= 2 ms GPU"],
    ]


def markdown(r: dict) -> str:
    c, t, inf = r["context"], r["training_it_s"], r["inference"]
    lines = [
        "| measurement | value |",
        "|---|---|",
    ]
    for B in r["batches"]:
        for k, label in TRAIN_KINDS.items():
            lines.append(f"| train it/s, batch {B}: {label} | {t[f'{k}@{B}']:.2f} |")
    comp = r.get("compile") or {}
    if comp:
        B = comp["batch"]
        lines += [
            f"| train it/s, batch {B}: conv_s2s + adversarial, eager (`compile.enabled=false`) | "
            f"{comp['eager']:.2f} |",
            f"| train it/s, batch {B}: conv_s2s + adversarial, compiled (`compile.enabled=true`) | "
            f"{comp['compiled']:.2f} |",
            f"| first 3 steps of both (compiling) s | {comp['warm_up_s']:.0f} |",
        ]
    compiled = r.get("train_compiled", {})
    lines.append(
        "| training steps above compiled (`compile.enabled=false`, the default) | "
        + (
            "yes"
            if compiled and all(compiled.values())
            else "no"
            if not any(compiled.values())
            else ", ".join(f"{k}: {'yes' if v else 'no'}" for k, v in compiled.items())
        )
        + " |"
    )
    lines += [
        f"| latency batch 1, 50->25: median ms | {inf['latency_ms_median']:.1f} |",
        f"| latency batch 1: p90 ms | {inf['latency_ms_p90']:.1f} |",
        f"| throughput batch {inf['throughput_batch']}: sequences/s | "
        f"{inf['throughput_seq_s']:.0f} |",
        f"| FLOPs per prediction (GFLOP) | {inf['flops_per_prediction'] / 1e9:.3f} |",
        f"| achieved GFLOP/s at batch 1 | {inf['gflops_achieved_b1']:.2f} |",
    ]
    pred = r.get("compiled_prediction") or {}
    if pred:
        lines += [
            f"| latency batch 1, forward() eager: median ms | {pred['eager_ms']:.1f} |",
            "| latency batch 1, forward() compiled (MotionForecaster compile=True): median ms | "
            f"{pred['compiled_ms']:.1f} |",
            f"| compiled prediction: first 3 calls (compiling) s, max abs diff from eager | "
            f"{pred['warm_up_s']:.0f}, {pred['max_diff']:.1e} |",
        ]
    for k in ("conv_adv", "conv", "gru"):
        B = r["batches"][0]
        g = r["train_flops"][f"{k}@{B}"] * t[f"{k}@{B}"] / 1e9
        lines.append(f"| achieved GFLOP/s training {k}, batch {B} | {g:.2f} |")
    lines.append(
        f"| machine float32 matmul GFLOP/s (n={r['matmul_n']}) | {r['matmul_gflops']:.1f} |"
    )
    d = r["data"]
    if "windows_per_s" in d:
        lines += [
            f"| data: cached DataModule setup s | {d['cached_setup_s']:.2f} |",
            f"| data: train windows sampled/s | {d['windows_per_s']:.0f} |",
        ]
    lines.append(f"| data | {d['note']} |")
    for name, share, calls in r.get("profile", []):
        lines.append(
            f"| share of a conv_s2s + adversarial step (batch {r['batches'][0]}), self time: "
            f"`{name}` ({calls:.0f} calls) | {100 * share:.1f}% |"
        )
    bound = r.get("arithmetic_bound") or {}
    if bound:
        lines += [
            f"| share of that step in convolutions and matrix products (self time) | "
            f"{100 * bound['share']:.1f}% |",
            "| that arithmetic alone, s per iteration (profiler self time; the bound with "
            f"everything else free), and as it/s | {bound['s_per_it']:.3f}, {bound['its']:.2f} |",
        ]
    lines += [
        f"| validation pass (120 windows) s | {r['validation_s']:.3f} |",
        f"| validation / (val_every={r['val_every']} train its, conv_adv batch "
        f"{r['batches'][0]}) | {r['validation_fraction']:.4f} |",
    ]
    cli = r.get("train_cli") or {}
    if cli:
        B0 = r["batches"][0]
        lines += [
            f"| `src.train` it/s, {cli['device']}: li2018_h36m (conv_s2s + adversarial) | "
            f"{cli['conv_adv']:.2f} |",
            f"| `src.train` it/s, {cli['device']}: li2018_h36m at commit {cli['ref']} | "
            + (f"{cli['conv_adv_ref']:.2f} |" if cli.get("conv_adv_ref") else "- |"),
            f"| `src.train` it/s, {cli['device']}: martinez2017_res_sup (gru_s2s) | "
            f"{cli['gru']:.2f} |",
            f"| `src.train` / bare loop, conv_s2s + adversarial, batch {B0} | "
            f"{cli['conv_adv'] / t[f'conv_adv@{B0}']:.2f} |",
            f"| `src.train` / bare loop, gru_s2s, batch {B0} | {cli['gru'] / t[f'gru@{B0}']:.2f} |",
        ]
    lines += ["", "The speed targets, measured by this run:", ""]
    lines += ["| measurement | now | target |", "|---|---|---|"]
    for name, now, goal in r.get("issue_targets", []):
        lines.append(f"| {name} | {now} | {goal} |")
    targets = r["targets"]
    lines += ["", "| target | measured | met |", "|---|---|---|"]
    for name, (value, ok) in targets.items():
        lines.append(f"| {name} | {value} | {'yes' if ok else 'NO'} |")
    head = [
        f"Command: `{r['command']}`  ",
        f"Date: {r['date']}  ",
        f"Commit: {c['commit']}  ",
        f"Machine: {c['cpu']}, {c['cores']} cores, torch {c['torch']} with "
        f"{c['torch_threads']} threads, device {c['device']}",
        "",
    ]
    return "\n".join(head + lines + NOTES) + "\n"


NOTES = [
    "",
    "Notes (generated text, no hand-typed numbers):",
    "",
    "- Times are medians of interleaved repeats (A/B variants alternate, so background load",
    "  hits both alike); on a shared, loaded machine absolute values are noisy, ratios less so.",
    "- Prediction encodes each of the 25 short-term windows anew (eq. 4), as training does.",
    "- The bound rows: the profiler's self time of the step's convolutions and matrix products",
    "  (at this run's speed of those kernels) as a share of the step, and the speed the step",
    "  would reach if nothing else took time. A speed-up over the reference commit beyond it",
    "  needs fewer FLOPs or faster kernels, not less overhead; what separates the step from it",
    "  is mostly the dropout draws (a fresh mask per window, as in the reference), the padding",
    "  copies and element-wise work (the share rows above).",
    "- The training step's optimisers are fused Adam, and the L2 terms of eq. (9) and of the",
    "  discriminator are added to the gradients in closed form (src/lit/predictor.py).",
    "- `compile.enabled=true` compiles the training step's two objectives (mode",
    "  reduce-overhead: on CUDA each one's forward and backward replayed as a CUDA graph); the",
    "  eager and compiled rows above compare the two on this run's device. It is off by",
    "  default on every device; on a GPU `python benchmarks/gpu_check.py` measures it",
    "  (docs/performance_cuda.md).",
    "- Compiled prediction (`MotionForecaster(compile=True)`, `compile_for_prediction` in",
    "  src/inference.py) uses mode reduce-overhead on CUDA (a CUDA graph per shape) and the",
    "  default mode on the CPU, where reduce-overhead measured slower; it is off by default,",
    "  and each new shape compiles for tens of seconds.",
]


START, END = "<!-- benchmark:start -->", "<!-- benchmark:end -->"


def write_page(path: Path, table: str) -> None:
    """The benchmark's table goes between the page's markers, so the hand-written sections of
    docs/performance.md around it stay; a page without markers is a new file."""
    if path.is_file() and START in (text := path.read_text()) and END in text:
        head, rest = text.split(START, 1)
        table = f"{head}{START}\n{table}{END}{rest.split(END, 1)[1]}"
    else:
        table = f"# Performance\n\n{START}\n{table}{END}\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(table)
