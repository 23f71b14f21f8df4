"""Write the protocol's test windows src.eval scores, as raw exp-map frames, to a .npz for a
model outside this project (scoring them: src/scoring.py).

    python -m src.export_windows data=h36m protocol=srnn out=windows.npz
    python -m src.export_windows data=cmu protocol=random data.allow_partial=true out=cmu.npz
"""

import hashlib
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from src.cli import hydra_entry
from src.config import check
from src.data.base import MotionDataModule, window_ids
from src.data.files import atomic_write
from src.lit.factory import ConfigError, build_test_data


def windows_sha256(ids: Iterable[str], frames: Iterable[np.ndarray]) -> str:
    """SHA-256 over each window's id and its observed + future frames (float32, C order), in
    the protocol's order: equal for equal windows, whoever computes it from whatever copy."""
    digest = hashlib.sha256()
    for name, window in zip(ids, frames, strict=True):
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(window, dtype=np.float32).tobytes())
    return digest.hexdigest()


def window_arrays(dm: MotionDataModule, dataset: str) -> dict[str, np.ndarray]:
    """A set-up datamodule's test windows, in the protocol's order:
    - ``observed`` (N, observed_len, F), ``future`` (N, future_len, F): raw exp-map frames,
      float32, downsampled as everywhere (§1.3); F = 99 on H3.6M, 117 on CMU;
    - ``action``, ``window_id`` (`window_ids`): (N,) strings; 0-d metadata: ``dataset`` (the data
      config's name: ``synthetic`` is not H3.6M), ``protocol``, ``fps`` (25, on CMU too, as the
      tables' horizons assume, protocol §1.5), ``data_sha256`` (`windows_sha256`)."""
    frames = np.stack([dm.raw_window(i) for i in range(len(dm.eval_windows))])
    ids = window_ids(dm.eval_windows)
    return {
        "observed": frames[:, : dm.observed_len],
        "future": frames[:, dm.observed_len :],
        "action": np.array([w.action for w in dm.eval_windows]),
        "window_id": np.array(ids),
        "dataset": np.array(dataset),
        "protocol": np.array(dm.eval_protocol),
        "fps": np.array(1000.0 / dm.frame_ms),
        "data_sha256": np.array(windows_sha256(ids, frames)),
    }


def export(cfg: DictConfig) -> Path:
    """Write the windows of `data=` under `protocol=` to `out=`; return its path."""
    check(cfg, "export_windows")
    out = Path(cfg.out) if cfg.get("out") else Path(cfg.paths.output_dir) / "windows.npz"
    if out.suffix != ".npz":
        raise ConfigError(f"out={out}: name a .npz file, e.g. out=windows.npz")
    if out.exists():
        raise ConfigError(f"out={out} already exists; nothing was overwritten. Name a new file.")
    dm = build_test_data(cfg)
    arrays = window_arrays(dm, cfg.data.name)
    atomic_write(out, lambda tmp: np.savez_compressed(tmp, **arrays))  # no half file, if killed
    absent = "".join(f"\n  absent: {a} ({why})" for a, why in dm.absent_actions.items())
    print(
        f"{len(arrays['window_id'])} {cfg.data.name} test windows, protocol={dm.eval_protocol} "
        f"({', '.join(dict.fromkeys(arrays['action']))}): observed {arrays['observed'].shape}, "
        f"future {arrays['future'].shape} at {float(arrays['fps']):g} fps{absent}\nwritten to {out}"
    )
    return out


main = hydra_entry("export_windows")(export)  # refused before writing: its folder goes


if __name__ == "__main__":
    main()
