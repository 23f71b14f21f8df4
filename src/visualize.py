"""Draw one evaluation window: ground truth, the model's prediction and zero-velocity.

    python -m src.visualize ckpt_path=outputs/train/runs/<run>/<time>/checkpoints/last.ckpt
    python -m src.visualize model=zero_velocity data=h36m action=walking
    python -m src.visualize model=zero_velocity data=cmu action=basketball window=3 format=mp4

The window is the `window`-th evaluation window of `action` (protocol §3: on H3.6M the SRNN
windows of S5, on CMU the test file windows). The model predicts the future fully
autoregressively from the 50 observed frames; prediction and ground truth are unnormalised
(protocol §2.2) and turned into joint positions by forward kinematics with the global
translation and rotation zeroed (as the metric does, protocol §4.1), then y and z swapped so
the person stands upright. Writes into the run's own folder (outputs/visualize/runs/...):

- `<action>_w<window>.gif` (or .mp4 when ffmpeg exists): the motions side by side as 3D
  stick figures, observed frames grey, future frames coloured;
- `<action>_w<window>_strip.png`: a frame strip in the manner of Li et al. (2018) Figure 3.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import matplotlib
from omegaconf import DictConfig

from src.cli import hydra_entry
from src.data.base import MotionDataModule
from src.lit.config import check
from src.lit.factory import ConfigError, build_for_evaluation
from src.lit.run_folders import nothing_left_if_refused
from src.metrics.kinematics import Skeleton
from src.plots import animate, frame_strip, window_rows

log = logging.getLogger(__name__)


def select_window(dm: MotionDataModule, action: str, window: int) -> int:
    """Index into `dm.eval_windows` of the `window`-th evaluation window of `action`."""
    if action not in dm.actions:
        raise ConfigError(f"action={action!r} is not in this data's actions: {dm.actions}")
    if action in dm.absent_actions:
        raise ConfigError(
            f"action={action!r} cannot be shown: {dm.absent_actions[action]}. Pick another "
            f"action, e.g. action={dm.eval_windows[0].action}"
        )
    indices = [i for i, w in enumerate(dm.eval_windows) if w.action == action]
    if not 0 <= window < len(indices):
        raise ConfigError(
            f"window={window} is out of range: {action} has {len(indices)} evaluation windows "
            f"(0..{len(indices) - 1}) under the {dm.eval_protocol} protocol"
        )
    return indices[window]


def _writer(fmt: str, fps: float):
    from matplotlib.animation import FFMpegWriter, PillowWriter

    if fmt == "mp4":
        if shutil.which("ffmpeg"):
            return FFMpegWriter(fps=fps), "mp4"
        print("format=mp4 needs ffmpeg, which is not installed; writing a GIF instead")
        log.warning("ffmpeg not found; writing a GIF instead of an MP4")
    return PillowWriter(fps=fps), "gif"


def visualize(cfg: DictConfig) -> dict[str, Path]:
    """Write the animation and the frame strip of one window; return their paths."""
    matplotlib.use("Agg")
    check(cfg, "visualize")  # window's range depends on the action: select_window names it
    dm, module = build_for_evaluation(cfg)
    observed_shown = min(int(cfg.observed_shown), dm.observed_len)
    rows, n_obs, what = window_rows(
        dm,
        module,
        select_window(dm, cfg.action, int(cfg.window)),
        bool(cfg.baseline),
        observed_shown,
        dataset=module.run_info["config"]["data"]["name"],
    )
    skeleton = Skeleton.load(module.dataset)
    out_dir = Path(cfg.paths.output_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{cfg.action}_w{cfg.window}"

    strip = frame_strip(rows, skeleton, n_obs, dm.frame_ms, step=cfg.strip_step, title=what)
    strip_path = out_dir / f"{stem}_strip.png"
    strip.savefig(strip_path)

    anim = animate(rows, skeleton, n_obs, dm.frame_ms, title=what)
    writer, ext = _writer(cfg.format, 1000 / dm.frame_ms)
    anim_path = out_dir / f"{stem}.{ext}"
    anim.save(anim_path, writer=writer)

    print(f"{what}\nwritten: {anim_path}\n         {strip_path}")
    return {"animation": anim_path, "strip": strip_path}


@hydra_entry("visualize")
def main(cfg: DictConfig) -> None:
    # Refused before drawing (the pictures are written last): its folder goes.
    with nothing_left_if_refused(started=None):
        visualize(cfg)


if __name__ == "__main__":
    main()
