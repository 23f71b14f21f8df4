"""The page of benchmarks/gpu_check.py (docs/performance_cuda.md) from the results dict its
main() collects: what ran, what was skipped or failed, and the measurements, in markdown."""

from __future__ import annotations

from collections import Counter

# What the check runs, named on the page too.
EXPERIMENTS = ("li2018_h36m", "martinez2017_res_sup")
CUDA_TEST_FILES = ("tests/test_compile.py", "tests/test_inference.py", "tests/test_checkpoints.py")
EQUALITY_TEST = "test_compiled_step_gives_the_eager_step_losses"


def _f(value, fmt: str, none: str = "-") -> str:
    return none if value is None else format(value, fmt)


def render(r: dict) -> str:
    lines = ["# GPU check", ""]
    if not r["cuda"]:
        lines += [
            "**No CUDA device**: torch sees none on this machine. Only what the CPU can check",
            "quickly ran; the CUDA tests, the compiled trainings and the host-sync count did",
            "not.",
            "",
        ]
    c = r["context"]
    lines += [
        f"Command: `{r['command']}`  ",
        f"Date: {r['date']}, commit {c['commit']}, torch {c['torch']}, device "
        f"{r['device_name']}, CPU {c['cpu']} ({c['cores']} cores)  ",
        f"Data: {r['data']}; ready in {_f(r.get('data_s'), '.0f')} s before the runs",
        "",
        "## Summary",
        "",
    ]
    runs = {x["label"]: x for x in r["train"]}
    for exp in EXPERIMENTS:
        eager, comp = runs.get(f"{exp}, eager"), runs.get(f"{exp}, compiled")
        text = f"- {exp}: eager {_f(eager and eager.get('its'), '.2f')} it/s"
        if comp and comp.get("its") and eager and eager.get("its"):
            text += f", compiled {comp['its']:.2f} it/s ({comp['its'] / eager['its']:.2f}x)"
        elif comp:
            text += f", compiled: {comp['status']}"
        lines.append(text + ";")
    lat = r["latency"]
    lines.append(
        f"- prediction at batch 1: {_f(lat.get('eager_ms'), '.1f')} ms eager"
        + (f", {lat['compiled_ms']:.1f} ms compiled" if "compiled_ms" in lat else "")
        + ";"
    )
    syncs = r["syncs"]
    lines.append(
        "- host syncs per training iteration: "
        + (f"{syncs['per_iteration']:.1f}" if "per_iteration" in syncs else syncs["status"])
        + ";"
    )
    cases = r["tests"].get("cases", [])
    tally = Counter(outcome for _, outcome, _, _ in cases)
    lines.append(
        "- CUDA tests: "
        + (", ".join(f"{n} {k}" for k, n in sorted(tally.items())) or r["tests"]["status"])
        + "."
    )

    lines += ["", "## CUDA tests", ""]
    if cases:
        lines += [
            f'`pytest -m "slow or not slow" -k cuda {" ".join(CUDA_TEST_FILES)}`: '
            f"{r['tests']['status']}.",
            "",
            "| test | outcome | s | detail |",
            "|---|---|---:|---|",
        ]
        lines += [f"| `{n}` | {o} | {t:.1f} | {d} |" for n, o, t, d in cases]
    else:
        lines.append(f"Not run: {r['tests']['status']}.")

    lines += ["", "## Eager and compiled training step: objectives (8) and (9), TF32 off", ""]
    equality = [x for x in cases if EQUALITY_TEST in x[0] and "cuda" in x[0]]
    if equality:
        lines.append(
            "Three iterations of each objective compiled (mode reduce-overhead: CUDA graphs) "
            "against eager, both drawing dropout masks from uniform numbers (eager CUDA "
            "dropout's fused kernel draws masks no compiled graph reproduces): losses within a "
            f"relative 1e-4 (`tests/test_compile.py::{EQUALITY_TEST}`)."
        )
        lines += [""] + [f"- `{n.split('::')[1]}`: {o} {d}".rstrip() for n, o, _, d in equality]
    else:
        lines.append(f"Not run: {r['tests']['status']}.")

    lines += [
        "",
        "## Training through `src.train`",
        "",
        f"`python -m src.train experiment=E {' '.join(r['train_overrides'])}`, "
        "with `compile.enabled=false` (eager) or `true` (compiled). Time to the first step: "
        "from the command's start (imports, data, compiling) to the end of iteration 1. "
        "Steady it/s: between the progress lines after the first tenth of the run.",
        "",
        "| run | iterations | time to first step (s) | steady it/s | wall (s) | status |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for x in r["train"]:
        lines.append(
            f"| {x['label']} | {x.get('iterations_done', 0)} | {_f(x.get('first_step_s'), '.1f')}"
            f" | {_f(x.get('its'), '.2f')} | {_f(x.get('wall_s'), '.0f')} | {x['status']} |"
        )

    lines += ["", "## Prediction latency, batch 1", ""]
    lines.append(
        "forward() of conv_s2s (the paper's sizes), 50 -> 25 frames, median of "
        f"{r['latency_repeats']} calls: eager {_f(lat.get('eager_ms'), '.1f')} ms"
        + (
            f"; compiled (`compile_for_prediction`) {lat['compiled_ms']:.1f} ms, first 3 calls "
            f"{lat['warm_up_s']:.0f} s, max abs difference from eager {lat['max_diff']:.1e}"
            if "compiled_ms" in lat
            else "; compiled: not measured (" + lat.get("note", "needs CUDA") + ")"
        )
        + "."
    )

    lines += ["", "## Host syncs per training iteration", ""]
    if "sites" in syncs:
        lines += [
            f"`src.train experiment=li2018_h36m data=synthetic trainer=gpu` (eager), iterations "
            f"11 to {10 + syncs['window']}: {syncs['per_iteration']:.1f} per iteration. Each "
            "stalls the GPU's launch queue until the work queued so far is done.",
            "",
            "| where | per iteration |",
            "|---|---:|",
        ]
        lines += [
            f"| `{site}` | {n / syncs['window']:.2f} |" for site, n in syncs["sites"].most_common()
        ]
    else:
        lines.append(f"Not counted: {syncs['status']}.")
    lines += ["", f"Steps skipped for the time budget: {', '.join(r['skipped']) or 'none'}."]
    lines += [f"Steps that failed: {'; '.join(r['failed']) or 'none'}."]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- main
