"""Training speed of `python -m src.train` itself (Trainer, callbacks, logging, data), side by
side with the same command at another commit.

    python benchmarks/train_cli.py [--ref 58436ca] [--experiment li2018_h36m] [--device cpu]
                                   [--iterations 60] [--markdown docs/train_speed.md]

Each commit runs the command twice, for `short` and `iterations` iterations (validation only
at the end of each), and the speed is (iterations - short) / (wall(long) - wall(short)): the
start-up, data loading and the final validation cancel out, so the figure is the steady-state
cost of an iteration as a user's run pays it. The reference commit is checked out into a
temporary git worktree and run with this checkout's Python environment. Runs alternate
between the commits so that background load hits both alike.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_once(tree: Path, overrides: list[str], out: Path, threads: int) -> float:
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "PYTHONUNBUFFERED": "1"}
    env.setdefault("MOTION_DATA_DIR", str(ROOT / "data"))  # both trees share one parsed cache
    cmd = [sys.executable, "-m", "src.train", *overrides, f"hydra.run.dir={out}"]
    start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise SystemExit(f"error: {' '.join(cmd)} failed in {tree}:\n{proc.stderr[-2000:]}")
    return wall


def measure(
    ref: str | None,
    experiment: str,
    device: str = "cpu",
    iterations: int = 60,
    short: int = 20,
    threads: int = 1,
    repeats: int = 1,
    overrides: tuple[str, ...] = (),
) -> dict[str, float]:
    """Steady-state it/s of `src.train experiment=<experiment>` in this checkout (key "this
    checkout") and, with `ref`, at that commit (key "commit <ref>"), runs alternating."""
    if not 0 < short < iterations:
        raise SystemExit("error: need 0 < short < iterations")
    trees = {"this checkout": ROOT}
    tmp = Path(tempfile.mkdtemp(prefix="train_cli_"))
    if ref:
        ref_tree = tmp / "ref"
        subprocess.run(["git", "worktree", "add", "-f", "--detach", str(ref_tree), ref],
                       cwd=ROOT, check=True, capture_output=True)  # fmt: skip
        trees[f"commit {ref}"] = ref_tree
    base = [
        f"experiment={experiment}",
        "data.allow_partial=true",
        f"trainer={device}",
        "media_every=0",
        "trainer.enable_progress_bar=false",
        *overrides,
    ]
    walls: dict[tuple[str, int], list[float]] = {}
    runs = 0
    try:
        # An untimed run per tree first: a fresh checkout compiles its .pyc files and reads
        # the data cache from disk in its first run, which would inflate the short run only.
        for rep in range(-1, repeats):
            for n in (short, iterations) if rep >= 0 else (short,):
                for name, tree in trees.items():
                    runs += 1
                    over = [*base, f"iterations={n}", f"val_every={n}"]
                    wall = run_once(tree, over, tmp / f"run{runs}_{n}", threads)
                    if rep >= 0:
                        walls.setdefault((name, n), []).append(wall)
    finally:
        if ref:
            subprocess.run(["git", "worktree", "remove", "--force", str(tmp / "ref")],
                           cwd=ROOT, capture_output=True)  # fmt: skip
    return {
        name: (iterations - short) / (min(walls[(name, iterations)]) - min(walls[(name, short)]))
        for name in trees
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", default="58436ca", help="commit to compare with ('' for none)")
    ap.add_argument("--experiment", default="li2018_h36m")
    ap.add_argument("--device", default="cpu", choices=["cpu", "gpu"])
    ap.add_argument("--iterations", type=int, default=60)
    ap.add_argument("--short", type=int, default=20)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--markdown", type=Path)
    ap.add_argument("--override", action="append", default=[], help="extra src.train override")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    from src.cli import git_commit  # the label the runs' own provenance uses

    speed = measure(
        args.ref,
        args.experiment,
        args.device,
        args.iterations,
        args.short,
        args.threads,
        args.repeats,
        tuple(args.override),
    )
    lines = [
        "# Training speed through `src.train`",
        "",
        f"Command: `python benchmarks/train_cli.py {' '.join(sys.argv[1:])}`  ",
        f"Date: {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, this checkout at commit "
        f"{git_commit()}, {args.threads} torch thread(s), {os.cpu_count()} cores  ",
        f"Steady-state iterations/s of `python -m src.train experiment={args.experiment} "
        f"data.allow_partial=true {' '.join([f'trainer={args.device}', *args.override])}`, "
        f"from runs of {args.short} and "
        f"{args.iterations} iterations (best of {args.repeats}).",
        "",
        "| code | it/s | s/iteration |",
        "|---|---:|---:|",
    ]
    for name, v in speed.items():
        lines.append(f"| {name} | {v:.3f} | {1 / v:.3f} |")
    if args.ref:
        ratio = speed["this checkout"] / speed[f"commit {args.ref}"]
        lines += ["", f"Speed-up of this checkout over {args.ref}: {ratio:.2f}x"]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown:
        args.markdown.write_text(text)


if __name__ == "__main__":
    main()
