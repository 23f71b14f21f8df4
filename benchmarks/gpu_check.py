"""The first thing to run on a GPU: what this project has never measured there, in one page.

    python benchmarks/gpu_check.py --archives $MOTION_ARCHIVES --out docs/performance_cuda.md

On a CUDA device, within about 10 minutes (--budget-s; what does not fit is named as skipped):

1. host syncs per training iteration (`torch.cuda.set_sync_debug_mode`), by call site;
2. prediction latency at batch 1, eager and compiled (`compile_for_prediction`);
3. `python -m src.train` for li2018_h36m and martinez2017_res_sup, eager: time to the first
   step and steady iterations/s;
4. the CUDA tests (tests whose name says cuda), among them the equality of the eager and the
   compiled training step, objectives (8) and (9), with TF32 off;
5. the same two trainings compiled (`compile.enabled=true`), last: compiling takes minutes.

Without --archives the trainings use `data=synthetic` (same shapes; the page says so). Without
a CUDA device the page and the output say so first, and it checks quickly what the CPU can
(1, 4 and 5 need CUDA): eager trainings of --iterations (default 10) and eager latency.
Exit status 1 when a test or a training failed.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import warnings
import xml.etree.ElementTree as ET
from collections import Counter, deque
from datetime import datetime, timezone
from functools import partial
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from benchmarks.benchmark import FUT, OBS, D, bench_compiled_prediction, conv_net, timed  # noqa: E402
from benchmarks.data_loading import machine_info  # noqa: E402
from benchmarks.gpu_check_page import (  # noqa: E402
    CUDA_TEST_FILES,
    EQUALITY_TEST,  # noqa: F401  (the check's name for it; tests read it here)
    EXPERIMENTS,
    _f,
    render,
)

# Files with CUDA-only tests; `-k cuda` picks them (and the few CPU tests naming CUDA).
PROGRESS = re.compile(r"iteration (\d+)/(\d+)")
SYNC_WARNING = "synchronizing CUDA operation"


class Budget:
    """Seconds left of --budget-s; a step that would need more is skipped, not started."""

    def __init__(self, seconds: float):
        self.end = time.monotonic() + seconds

    def left(self) -> float:
        return self.end - time.monotonic()


# ---------------------------------------------------------------------------- measurements
def prepare_data(data: list[str], data_dir: Path, work: Path) -> float:
    """Unpack and parse the archives (or write the synthetic data) before any run is timed:
    the first run would pay it, once."""
    from src.build import build_datamodule
    from src.prepare import compose_config

    start = time.perf_counter()
    for exp in EXPERIMENTS:
        cfg = compose_config("train", [f"experiment={exp}", *data], work / "data", data_dir)
        dm = build_datamodule(cfg.data)
        dm.prepare_data()
        dm.setup("fit")
    return time.perf_counter() - start


def count_host_syncs(
    data_dir: Path, work: Path, overrides: tuple[str, ...] = (), skip: int = 10, window: int = 20
) -> dict:
    """Host syncs per iteration of `src.train experiment=li2018_h36m` (synthetic data, the
    default settings, eager), counted over iterations skip+1 .. skip+window by the warnings of
    `torch.cuda.set_sync_debug_mode("warn")`, by the line that caused them."""
    from src.lit.predictor import MotionPredictor
    from src.prepare import compose_config
    from src.train import train

    n = skip + window + 1
    cfg = compose_config(
        "train",
        ["experiment=li2018_h36m", "data=synthetic", "trainer=gpu", f"iterations={n}",
         f"val_every={n}", "media_every=0", *overrides],
        work / "syncs",
        data_dir,
    )  # fmt: skip
    batches = 0

    def on_train_batch_start(module, batch, batch_idx):  # the window: every hook in between
        nonlocal batches
        batches += 1
        if batches == skip + 1:
            torch.cuda.set_sync_debug_mode("warn")
        elif batches == skip + window + 1:
            torch.cuda.set_sync_debug_mode(0)

    hook = mock.patch.object(MotionPredictor, "on_train_batch_start", on_train_batch_start)
    try:
        with hook, warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            train(cfg)
    finally:
        torch.cuda.set_sync_debug_mode(0)
    sites = Counter(
        f"{_short(w.filename)}:{w.lineno}" for w in caught if SYNC_WARNING in str(w.message)
    )
    return {"window": window, "per_iteration": sum(sites.values()) / window, "sites": sites}


def _short(filename: str) -> str:
    """A file of the project relative to its root, of an installed package from its name."""
    path = Path(filename)
    if path.is_relative_to(ROOT):
        return str(path.relative_to(ROOT))
    parts = path.parts
    return (
        "/".join(parts[parts.index("site-packages") + 1 :])
        if "site-packages" in parts
        else filename
    )


def prediction_latency(device: torch.device, repeats: int) -> dict:
    """Median ms of forward() at batch 1 (50 -> 25 frames, the paper's conv_s2s), eager and,
    on CUDA, compiled (benchmarks/benchmark.py's measurement)."""
    if device.type == "cuda":
        return bench_compiled_prediction(device, repeats)
    net, x1 = conv_net().eval(), torch.randn(1, OBS, D)
    with torch.inference_mode():
        net(x1, FUT)
        times = timed(partial(net, x1, FUT), device, repeats)
    return {"eager_ms": 1e3 * statistics.median(times)}


def train_run(label: str, overrides: list[str], env: dict, timeout: float) -> dict:
    """`python -m src.train` with a progress line every second; each line's arrival gives
    (iteration, seconds since the command started)."""
    cmd = [sys.executable, "-m", "src.train", *overrides]
    start = time.perf_counter()
    proc = subprocess.Popen(
        cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    killed = threading.Event()

    def kill() -> None:
        killed.set()
        proc.kill()

    timer = threading.Timer(timeout, kill)
    timer.start()
    points: list[tuple[int, float]] = []
    tail: deque[str] = deque(maxlen=30)
    for line in proc.stdout:
        tail.append(line.rstrip())
        if match := PROGRESS.search(line):
            points.append((int(match.group(1)), time.perf_counter() - start))
    proc.wait()
    timer.cancel()
    wall = time.perf_counter() - start
    if killed.is_set():
        status = f"stopped at the time limit ({timeout:.0f} s)"
    elif proc.returncode != 0:
        errors = [x for x in tail if x.startswith("error:")] or list(tail)[-3:]
        status = f"failed (exit {proc.returncode}): {' '.join(errors)[:300]}"
    else:
        status = "ok"
    return {"label": label, "status": status, "wall_s": wall, **_speed(points)}


def _speed(points: list[tuple[int, float]]) -> dict:
    """Steady it/s between the progress lines after the first tenth of the run (compiling and
    CUDA-graph recording happen in the first iterations); the time to the end of the first
    iteration, from the first line, back by the iterations it is past the first at that rate."""
    if not points:
        return {"its": None, "first_step_s": None, "iterations_done": 0}
    total = points[-1][0]
    steady = [p for p in points if p[0] > max(1, total // 10)]
    use = steady if len(steady) >= 2 else points
    its = None
    if len(use) >= 2 and use[-1][1] > use[0][1]:
        its = (use[-1][0] - use[0][0]) / (use[-1][1] - use[0][1])
    first_it, first_t = points[0]
    first = first_t - (first_it - 1) / its if its else first_t
    return {"its": its, "first_step_s": first, "iterations_done": total}


def cuda_tests(work: Path, env: dict, timeout: float) -> dict:
    files = [f for f in CUDA_TEST_FILES if (ROOT / f).is_file()]
    xml = work / "cuda_tests.xml"
    cmd = [sys.executable, "-m", "pytest", "-m", "slow or not slow", "-k", "cuda", "-q",
           "-p", "no:cacheprovider", f"--junitxml={xml}", *files]  # fmt: skip
    try:
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True,
                              timeout=timeout)  # fmt: skip
    except subprocess.TimeoutExpired:
        return {"status": f"stopped at the time limit ({timeout:.0f} s)", "cases": []}
    if not xml.is_file():
        return {"status": f"pytest failed to run: {proc.stderr[-300:]}", "cases": []}
    return {"status": f"exit {proc.returncode}", "cases": junit_cases(xml)}


def junit_cases(xml: Path) -> list[tuple[str, str, float, str]]:
    """(test id, passed / failed / skipped, seconds, first line of the reason) per test."""
    cases = []
    for case in ET.parse(xml).getroot().iter("testcase"):
        outcome, detail = "passed", ""
        for tag, said in (("failure", "failed"), ("error", "failed"), ("skipped", "skipped")):
            node = case.find(tag)
            if node is not None:
                outcome = said
                detail = (node.get("message") or "").strip().split("\n")[0][:200]
        name = f"{case.get('classname', '').replace('.', '/')}.py::{case.get('name')}"
        cases.append((name, outcome, float(case.get("time", 0)), detail.replace("|", "/")))
    return cases


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--archives", type=Path, help="folder with h3.6m.zip (else data=synthetic)")
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "gpu_check.md")
    ap.add_argument("--iterations", type=int, help="per training run (300 on CUDA, 10 on CPU)")
    ap.add_argument("--budget-s", type=float, default=570, help="for the whole check")
    args = ap.parse_args(argv)
    cuda = torch.cuda.is_available()
    device = torch.device("cuda" if cuda else "cpu")
    name = torch.cuda.get_device_name(0) if cuda else "none (no CUDA device)"
    print(f"CUDA device: {name}" if cuda else "NO CUDA DEVICE: checking on the CPU", flush=True)
    budget = Budget(args.budget_s)
    iterations = args.iterations or (300 if cuda else 10)
    data_dir = Path(os.environ.get("MOTION_DATA_DIR", ROOT / "data"))
    if args.archives:  # for this process's configs and the runs': conf/paths/default.yaml
        os.environ["MOTION_ARCHIVES"] = str(args.archives.resolve())
    env = {**os.environ, "MOTION_DATA_DIR": str(data_dir), "PYTHONUNBUFFERED": "1"}
    if args.archives:
        data = ["data.allow_partial=true"]
        data_text = f"the archives in {args.archives} (`data.allow_partial=true`)"
    else:
        data = ["data=synthetic"]
        data_text = "synthetic (`data=synthetic`: no --archives given), the real data's shapes"
    shown = sys.argv[1:] if argv is None else argv
    r: dict = {
        "command": " ".join(["python benchmarks/gpu_check.py", *shown]),
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "cuda": cuda,
        "device_name": name,
        "context": machine_info(),
        "data": data_text,
        "skipped": [],
        "failed": [],
        "train": [],
        "latency_repeats": 30 if cuda else 10,
    }  # fmt: skip
    trainer = "gpu" if cuda else "cpu"
    # The rate comes from the progress lines' arrival times, so a short run (the CPU test's)
    # needs a line per iteration; a long one a line a second (each line reads the iteration
    # counter, a host sync on a GPU).
    progress = 1 if iterations >= 50 else 0
    r["train_overrides"] = [
        *data, f"trainer={trainer}", f"iterations={iterations}", f"val_every={iterations}",
        "checkpoint_every=0", "media_every=0", f"progress_every_s={progress}",
        "trainer.enable_progress_bar=false",
    ]  # fmt: skip

    with tempfile.TemporaryDirectory(prefix="gpu_check_") as tmp:
        work = Path(tmp)

        def step(title: str, need_s: float, fn, default):
            """fn(), or `default` when the budget has less than need_s left; an error is
            recorded (the page is still written) and gives `default` too."""
            if budget.left() < need_s:
                r["skipped"].append(title)
                print(f"skipped (time budget): {title}", flush=True)
                return default
            print(f"{title} ...", flush=True)
            try:
                return fn()
            except Exception as err:  # report it on the page; the other steps still run
                traceback.print_exc()
                r["failed"].append(f"{title}: {type(err).__name__}: {str(err)[:300]}")
                return default

        def training(exp: str, compiled: bool, share: int = 1) -> None:
            """share: of the time left, this run may take 1/share (the runs still to come)."""
            label = f"{exp}, {'compiled' if compiled else 'eager'}"
            over = [
                f"experiment={exp}",
                *r["train_overrides"],
                f"compile.enabled={str(compiled).lower()}",
                f"hydra.run.dir={work / label.replace(', ', '_')}",
            ]
            result = step(
                f"src.train {label}",
                30,
                lambda: train_run(label, over, env, (budget.left() - 15) / share),
                {"label": label, "status": "skipped (time budget)"},
            )
            r["train"].append(result)
            print(f"  {result['status']}, {_f(result.get('its'), '.2f')} it/s", flush=True)

        r["data_s"] = step("data", 0, lambda: prepare_data(data, data_dir, work), None)
        missing = {"status": "skipped or failed (the end of the page says which)"}
        r["syncs"] = (
            step("host syncs", 60, lambda: count_host_syncs(data_dir, work), missing)
            if cuda
            else {"status": "needs a CUDA device"}
        )
        r["latency"] = step(
            "prediction latency",
            30,
            lambda: prediction_latency(device, r["latency_repeats"]),
            {"note": missing["status"]},
        )
        for exp in EXPERIMENTS:
            training(exp, compiled=False)
        r["tests"] = (
            step(
                "CUDA tests",
                60,
                # Half of what is left: the compiled trainings come after.
                lambda: cuda_tests(work, env, (budget.left() - 30) / 2),
                {"status": "skipped (time budget)"},
            )
            if cuda
            else {"status": "no CUDA device (they would all skip)"}
        )
        if cuda:
            for i, exp in enumerate(EXPERIMENTS):
                training(exp, compiled=True, share=len(EXPERIMENTS) - i)
        else:
            r["train"] += [
                {"label": f"{exp}, compiled", "status": "not run: needs CUDA (on the CPU, "
                 "docs/performance.md compares eager and compiled)"}
                for exp in EXPERIMENTS
            ]  # fmt: skip

    page = render(r)
    print(page)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(page)
    print(f"wrote {args.out}")
    failed = r["failed"] or any(o == "failed" for _, o, _, _ in r["tests"].get("cases", []))
    return 1 if failed or any(x["status"].startswith("failed") for x in r["train"]) else 0


if __name__ == "__main__":
    sys.exit(main())
