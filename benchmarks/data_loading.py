"""Time the data layer on the real archives: unpack, first parse, cached load, DataModule setup.

    python benchmarks/data_loading.py --archives /work/shared/data [--json out.json]

Each dataset is unpacked into a fresh temporary data_dir, so "first parse" is what a new user
pays once (text -> float32 arrays + cache), and "cached load" what every later run pays. The
unpacked files are in the OS page cache when they are parsed (they were just written).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from src.data import CMUDataModule, H36MDataModule  # noqa: E402
from src.data.archive import ensure_dataset  # noqa: E402
from src.data.cache import load_sequences  # noqa: E402
from src.data.layout import CMU, H36M, H36M_SUBJECTS, cmu_files, h36m_files  # noqa: E402


def machine_info() -> dict:
    cpu = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).resolve().parents[1],
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "none (no commit yet)"
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {
        "cpu": cpu,
        "cores": usable,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "torch": torch.__version__,
        "commit": commit,
    }


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def bench(spec, module_cls, relpaths, archives: Path) -> dict:
    with tempfile.TemporaryDirectory(prefix=f"bench_{spec.name}_") as tmp:
        data_dir = Path(tmp)
        _, unpack_s = _timed(lambda: ensure_dataset(spec, data_dir, archive_dir=archives))
        present = [r for r in relpaths if (data_dir / r).is_file()]
        arrays, parse_s = _timed(lambda: load_sequences(data_dir, spec, present))
        _, cached_s = _timed(lambda: load_sequences(data_dir, spec, present))
        dm = module_cls(data_dir, allow_partial=True)
        _, setup_s = _timed(dm.setup)
        return {
            "dataset": spec.name,
            "files": len(present),
            "frames": int(sum(len(a) for a in arrays.values())),
            "text_MB": round(sum((data_dir / r).stat().st_size for r in present) / 1e6, 1),
            "unpack_s": round(unpack_s, 2),
            "first_parse_s": round(parse_s, 2),
            "cached_load_s": round(cached_s, 2),
            "datamodule_setup_cached_s": round(setup_s, 2),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--archives", default=os.environ.get("MOTION_ARCHIVES"))
    parser.add_argument("--json", type=Path, help="write the results here")
    args = parser.parse_args()
    if not args.archives:
        parser.error(
            "pass --archives <folder with h3.6m.zip and cmu_mocap.zip> or set MOTION_ARCHIVES"
        )
    logging.basicConfig(level=logging.ERROR)  # the partial-copy warnings are expected here
    archives = Path(args.archives)

    info = machine_info()
    h36m_all = [e.relpath for e in h36m_files(H36M_SUBJECTS, H36M.actions, "all")]
    cmu_all = [e.relpath for split in ("train", "test") for e in cmu_files(CMU.actions, split)]
    rows = [
        bench(H36M, H36MDataModule, h36m_all, archives),
        bench(CMU, CMUDataModule, cmu_all, archives),
    ]

    print(
        f"Machine: {info['cpu']}, {info['cores']} cores; Python {info['python']}, "
        f"numpy {info['numpy']}, torch {info['torch']}; commit {info['commit']}\n"
    )
    cols = list(rows[0])
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for row in rows:
        print("| " + " | ".join(str(row[c]) for c in cols) + " |")
    if args.json:
        args.json.write_text(json.dumps({"machine": info, "results": rows}, indent=2) + "\n")
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
