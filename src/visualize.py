"""`python -m src.visualize` (usage: `--help`): the `window`-th evaluation window of `action`
(protocol §3) as stick figures (`<action>_w<window>.gif`, .mp4 with ffmpeg) and a frame strip as
Li et al. (2018) Figure 3 (`..._strip.png`): ground truth, the model's fully autoregressive
prediction and zero-velocity, global translation and rotation zeroed (§4.1), z up."""

import shutil
from pathlib import Path

from matplotlib.animation import FFMpegWriter, PillowWriter
from omegaconf import DictConfig

from src.cli import hydra_entry
from src.config import ConfigError, check
from src.data.base import MotionDataModule
from src.metrics.kinematics import Skeleton
from src.plots import animate, frame_strip, window_rows
from src.results import build_for_evaluation


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


def visualize(cfg: DictConfig) -> dict[str, Path]:
    """Write the animation and the frame strip of one window; return their paths."""
    check(cfg, "visualize")  # window's range depends on the action: select_window names it
    dm, module = build_for_evaluation(cfg)
    index = select_window(dm, cfg.action, int(cfg.window))
    shown = min(int(cfg.observed_shown), dm.observed_len)
    dataset = module.run_info["config"]["data"]["name"]
    rows, n_obs, what = window_rows(dm, module, index, bool(cfg.baseline), shown, dataset=dataset)
    skeleton = Skeleton.load(module.dataset)
    fps, mp4 = 1000 / dm.frame_ms, cfg.format == "mp4" and shutil.which("ffmpeg")
    if cfg.format == "mp4" and not mp4:
        print("format=mp4 needs ffmpeg, which is not installed; writing a GIF instead")
    Path(cfg.paths.output_dir).mkdir(parents=True, exist_ok=True)
    stem, ext = f"{cfg.paths.output_dir}/{cfg.action}_w{cfg.window}", "mp4" if mp4 else "gif"
    paths = {"animation": Path(f"{stem}.{ext}"), "strip": Path(f"{stem}_strip.png")}
    strip = frame_strip(rows, skeleton, n_obs, dm.frame_ms, step=cfg.strip_step, title=what)
    strip.savefig(paths["strip"])
    writer = FFMpegWriter(fps=fps) if mp4 else PillowWriter(fps=fps)
    animate(rows, skeleton, n_obs, dm.frame_ms, title=what).save(paths["animation"], writer=writer)
    print(f"{what}\nwritten: {paths['animation']}\n         {paths['strip']}")
    return paths


main = hydra_entry("visualize")(visualize)  # refused before drawing: its folder goes


if __name__ == "__main__":
    main()
