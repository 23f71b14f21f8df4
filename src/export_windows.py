"""Write the protocol's test windows src.eval scores, as raw exp-map frames, to a .npz for a
model outside this project (the arrays, and scoring them: src/scoring.py).

    python -m src.export_windows data=h36m protocol=srnn out=windows.npz
    python -m src.export_windows data=cmu protocol=random data.allow_partial=true out=cmu.npz
"""

from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from src.build import build_test_data
from src.cli import hydra_entry
from src.config import ConfigError, check
from src.data.files import atomic_write
from src.scoring import window_arrays


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
