"""Stick figures, frame strips and animations of motions (T, J, 3) of joint positions after
`yz_swap` (z up), observed frames grey, the future in the row's colour; and error curves.
Figures are `matplotlib.figure.Figure` (no pyplot): they render without a display."""

from __future__ import annotations

import textwrap
from typing import NamedTuple

import numpy as np
import torch
from matplotlib.animation import FuncAnimation
from matplotlib.figure import Figure

from src.data.synthetic import SyntheticDataModule
from src.metrics.kinematics import Skeleton, forward_kinematics, yz_swap
from src.models.baselines import ZeroVelocity

# (right side and spine, left side): two shades tell the limbs apart.
OBSERVED = ("#303030", "#9a9a9a")
VIEW = (12.0, -70.0)  # elevation and azimuth of the camera, degrees
PALETTE = {
    "green": ("#1a7f37", "#7fd18b"),
    "red": ("#c62828", "#f28b82"),
    "blue": ("#1f5fb4", "#8ab4f8"),
}
# Joints on the body's left: H3.6M's 1-5 and 24-31 as Martinez et al.'s viz.py (both arms point
# up in the rest pose, hence lists), CMU's chains at -x in the rest pose.
LEFT_JOINTS = {
    "h36m": frozenset([*range(1, 6), *range(24, 32)]),
    "cmu": frozenset([*range(8, 13), *range(30, 38)]),
}


class PoseRow(NamedTuple):
    """One motion to draw: a label, positions (T, J, 3) (observed then future), a PALETTE key."""

    label: str
    positions: np.ndarray
    color: str = "red"


def skeleton_bones(skeleton: Skeleton) -> list[tuple[int, int]]:
    """(parent, child) pairs, less zero-length bones (e.g. the H3.6M hand and thumb sites)."""
    offsets = skeleton.offsets.abs().sum(-1).tolist()
    return [(p, j) for j, p in enumerate(skeleton.parents) if j > 0 and offsets[j] > 0]


def bone_sides(skeleton: Skeleton, bones) -> np.ndarray:
    """1 for bones of the body's left side (drawn in the lighter shade), 0 otherwise."""
    left = LEFT_JOINTS.get(skeleton.name, frozenset())
    return np.array([int(c in left) for _, c in bones], dtype=int)


def positions(frames: torch.Tensor, skeleton: Skeleton) -> np.ndarray:
    """Joint positions (T, J, 3) of unnormalised frames (T, F), body frame, z up."""
    return yz_swap(forward_kinematics(frames.double(), skeleton, zero_global=True)).numpy()


@torch.no_grad()
def window_rows(
    dm, module, index: int, baseline: bool = True, observed_shown: int = 25,
    name: str | None = None, dataset: str | None = None
) -> tuple[list[PoseRow], int, str]:  # fmt: skip
    """(rows, n_observed, description) of evaluation window `index`: `module`'s prediction
    (dropout off), the ground truth and (`baseline`) zero-velocity, each the last `observed_shown`
    observed frames then the future. Titled with `dataset` (default: the data's own name)."""
    item = {k: v.to(module.device) for k, v in dm.test_dataloader().dataset[index].items()}
    was_training, T = module.training, len(item["future"])
    module.eval()
    try:
        pred = module(item["observed"][None], T, action=item["action"][None])[0]
    finally:
        module.train(was_training)
    frames = {"observed": item["observed"], "future": item["future"], "prediction": pred}
    frames = {k: module.normalizer.unnormalize(v).cpu() for k, v in frames.items()}
    obs = frames["observed"][-observed_shown:]
    skeleton = Skeleton.load(module.dataset)
    name = name or module.run_info.get("config", {}).get("model", {}).get("name")
    name = name or type(module.net).__name__
    shown = {"prediction": (f"prediction ({name})", "red"), "future": ("ground truth", "green")}
    if baseline and not isinstance(module.net, ZeroVelocity):
        frames["still"] = obs[-1:].expand(T, -1)  # zero-velocity repeats the last observed frame
        shown["still"] = ("zero-velocity", "blue")
    rows = [PoseRow(label, positions(torch.cat([obs, frames[k]]), skeleton), color)
            for k, (label, color) in shown.items()]  # fmt: skip
    w = dm.eval_windows[index]
    window = sum(v.action == w.action for v in dm.eval_windows[:index])  # among its action's
    data = dataset or ("synthetic" if isinstance(dm, SyntheticDataModule) else dm.dataset_name)
    what = f"{name} on {data}: {w.action}, window {window} ({w.sequence}, start {w.start})"
    return rows, len(obs), what


def _axes(fig, rows: int, cols: int, k: int, box, view):
    ax = fig.add_subplot(rows, cols, k, projection="3d")
    lo, hi = box
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]), proj_type="ortho")
    ax.set_box_aspect(tuple(hi - lo), zoom=1.35)
    ax.view_init(elev=view[0], azim=view[1])
    ax.set_axis_off()
    return ax


def _segments(pose: np.ndarray, bones) -> np.ndarray:
    """(3 * len(bones), 3) points: each bone's two ends, then a NaN row that breaks the line,
    so that one Line3D draws many bones (one artist per shade keeps animations fast)."""
    idx = np.asarray(bones, dtype=int).reshape(-1, 2)
    pts = np.full((len(idx), 3, 3), np.nan)
    pts[:, 0], pts[:, 1] = pose[idx[:, 0]], pose[idx[:, 1]]
    return pts.reshape(-1, 3)


def draw_skeleton(ax, pose, bones, colors=PALETTE["red"], sides=None, linewidth=2.0) -> list:
    """One pose (J, 3) in `colors` ((right and spine, left) or one; `sides`: 0/1 per bone); the
    two Line3D objects (right, left), which an animation moves with `set_data_3d`."""
    pair = (colors, colors) if isinstance(colors, str) else colors
    sides = np.zeros(len(bones), dtype=int) if sides is None else sides
    lines = []
    for side in (0, 1):
        half = [b for b, s in zip(bones, sides, strict=True) if s == side]
        lines += ax.plot(*_segments(np.asarray(pose), half).T, color=pair[side], lw=linewidth)
    return lines


def strip_frames(n_observed: int, n_total: int, step: int = 3, n_before: int = 3) -> list[int]:
    """`n_before` observed frames ending at the last observed one, then every `step`-th future
    frame counted back from the last."""
    if not 0 < n_observed < n_total or step < 1 or n_before < 0:
        raise ValueError(
            f"need 0 < n_observed < n_total, step >= 1, n_before >= 0: got "
            f"{n_observed}, {n_total}, {step}, {n_before}"
        )
    before = [n_observed - 1 - step * k for k in range(n_before)]
    after = list(range(n_total - 1, n_observed - 1, -step))
    return sorted(f for f in before if f >= 0) + sorted(after)


def _prepare(rows, skeleton: Skeleton, n_observed: int):
    """(T, bones, sides, box) of checked rows; box holds every pose: all panels share a scale."""
    if not rows:
        raise ValueError("nothing to draw: rows is empty")
    T = rows[0].positions.shape[0]
    for row in rows:
        if row.positions.ndim != 3 or row.positions.shape[0] != T or row.positions.shape[2] != 3:
            raise ValueError(
                f"row {row.label!r}: positions must be (T={T}, J, 3), got {row.positions.shape}"
            )
    if not 0 < n_observed < T:
        raise ValueError(f"n_observed={n_observed} must lie between 1 and T-1={T - 1}")
    bones = skeleton_bones(skeleton)
    pts = np.concatenate([r.positions.reshape(-1, 3) for r in rows])
    lo, hi = pts.min(0), pts.max(0)
    pad = 0.05 * float((hi - lo).max()) + 1e-9
    return T, bones, bone_sides(skeleton, bones), (lo - pad, hi + pad)


def frame_strip(
    rows, skeleton: Skeleton, n_observed: int, frame_ms: float = 40, step: int = 3,
    n_before: int = 3, title: str | None = None, view=VIEW, cell: float = 1.15
) -> Figure:  # fmt: skip
    """A grid of poses as Li et al. (2018) Figure 3: a row per motion, the last observed frames
    grey then future ones in colour, titled with the time from the last observed frame."""
    T, bones, sides, box = _prepare(rows, skeleton, n_observed)
    frames = strip_frames(n_observed, T, step, n_before)
    fig = Figure(figsize=(cell * len(frames) + 1.2, cell * 1.5 * len(rows) + 0.6), dpi=100)
    fig.subplots_adjust(left=0.08, right=1.0, bottom=0.0, top=0.86, wspace=-0.25, hspace=0.0)
    for r, row in enumerate(rows):
        for c, t in enumerate(frames):
            ax = _axes(fig, len(rows), len(frames), r * len(frames) + c + 1, box, view)
            colors = OBSERVED if t < n_observed else PALETTE[row.color]
            draw_skeleton(ax, row.positions[t], bones, colors, sides, linewidth=1.4)
            if r == 0:
                ms = (t - (n_observed - 1)) * frame_ms
                ax.set_title(f"{ms:+.0f} ms" if ms else "0 ms", fontsize=8, pad=0)
        y, color = 0.86 - (r + 0.5) * 0.86 / len(rows), PALETTE[row.color][0]
        fig.text(0.01, y, row.label, rotation=90, va="center", fontsize=9, color=color)
    what = "grey: observed, colour: future (time from the last observed frame)"
    fig.suptitle((title + "\n" if title else "") + what, fontsize=9)
    return fig


def animate(
    rows, skeleton: Skeleton, n_observed: int, frame_ms: float = 40, title: str | None = None,
    view=VIEW, size: float = 3.0, dpi: int = 80
) -> FuncAnimation:  # fmt: skip
    """The rows side by side, a frame per motion frame, grey until the first future frame. Save
    with `anim.save(path, writer=PillowWriter(fps=1000 / frame_ms))`."""
    T, bones, sides, box = _prepare(rows, skeleton, n_observed)
    fig = Figure(figsize=(size * len(rows), size + 0.7), dpi=dpi)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.8, wspace=0)
    all_lines = []
    for i, row in enumerate(rows):
        ax = _axes(fig, 1, len(rows), i + 1, box, view)
        ax.set_title(row.label, color=PALETTE[row.color][0], fontsize=10)
        all_lines.append(draw_skeleton(ax, row.positions[0], bones, OBSERVED, sides))
    clock = fig.suptitle("", fontsize=9)
    halves = [[b for b, s in zip(bones, sides, strict=True) if s == side] for side in (0, 1)]

    def update(t: int) -> list:
        for row, lines in zip(rows, all_lines, strict=True):
            pair = OBSERVED if t < n_observed else PALETTE[row.color]
            for line, half, color in zip(lines, halves, pair, strict=True):
                line.set_data_3d(*_segments(row.positions[t], half).T)
                line.set_color(color)
        ms = (t - (n_observed - 1)) * frame_ms
        phase = "observed" if t < n_observed else "predicted"
        clock.set_text((title + "\n" if title else "") + f"{ms:+.0f} ms ({phase})")
        return [line for lines in all_lines for line in lines]

    return FuncAnimation(fig, update, frames=range(T), interval=frame_ms, blit=False)


class Curve(NamedTuple):
    """A line: {x: y}, a ± band {x: std}, a colour index (None: the next), a line style."""

    label: str
    values: dict
    std: dict | None = None
    color: int | None = None
    style: str = "-"


def line_panels(
    panels, xlabel="prediction horizon (ms)", ylabel="Euler-angle error (rad)", from_zero=True
):
    """A panel per (title, curves), side by side, as Li et al. (2018) Figure 4. `from_zero=False`
    fits the y axis to the curves: a change of 0.1 rad over training is lost on an axis from 0."""
    if not panels or not all(curves for _, curves in panels):
        raise ValueError("line_panels: a panel without curves")
    fig = Figure(figsize=(5.0 * len(panels) + 1.0, 4.0), dpi=100)
    for k, (title, curves) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), k + 1)
        ticks: set[int] = set()
        for n, curve in enumerate(curves):
            xs = sorted(int(x) for x in curve.values)
            ys = np.array([curve.values.get(x, curve.values.get(str(x))) for x in xs])
            ticks.update(xs)
            color = f"C{(n if curve.color is None else curve.color) % 10}"
            ax.plot(xs, ys, curve.style, marker="o", ms=3, color=color, label=curve.label)
            if curve.std:
                std = np.array([curve.std.get(x, 0.0) for x in xs])
                ax.fill_between(xs, ys - std, ys + std, color=color, alpha=0.15, lw=0)
        if len(ticks) <= 12:
            ax.set_xticks(sorted(ticks))
        ax.set(xlabel=xlabel, ylabel=ylabel, ylim=(0, None) if from_zero else (None, None))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, handlelength=4)  # long enough to show a dashed line as dashed
        if title:  # a long protocol name would run past a 5-inch panel and be cut off
            ax.set_title(textwrap.fill(title, 48), fontsize=10)
    fig.tight_layout()
    return fig


def error_vs_horizon(results, title=None, ylabel="Euler-angle error (rad)", dashed=()) -> Figure:
    """A panel, a line per (label, {ms: value}); the labels in `dashed` dashed."""
    curves = [Curve(label, v, style="--" if label in dashed else "-") for label, v in results]
    return line_panels([(title, curves)], ylabel=ylabel)
