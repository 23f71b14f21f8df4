"""The Euler-angle error of Martinez et al. 2017 / Li et al. 2018 (protocol §4). Per test window:
unnormalised exp-map frames -> Euler angles per joint triple -> zero the global translation and
rotation (cols 0-5) -> keep the dims whose ground-truth Euler std over time is > 1e-4 -> per-frame
L2 norm of the difference over the kept dims (no angle wrapping); an action's table value is the
plain mean over its windows (§4.1 step 6). The dims come from the ground truth, never from the
prediction: that (the old bug of protocol §8) gives a constant prediction zero error."""

import torch
import torchmetrics
from torch import Tensor

from src.metrics.rotations import MetricInputError, expmap_to_euler

HORIZONS_MS = (80, 160, 320, 400, 560, 1000)
STD_THRESHOLD = 1e-4  # protocol §4.1 step 4
DIM_RULES = ("future", "window")


def horizon_frame_indices(frame_ms: float = 40, num_frames: int = 25) -> dict[int, int]:
    """Each horizon of HORIZONS_MS with its 0-based index < num_frames into the predicted frames.
    Frame k lies (k + 1) * frame_ms after the last observed one (protocol §4.3): 80 ms -> 1,
    160 -> 3, 320 -> 7, 400 -> 9, 560 -> 13, 1000 -> 24 at 40 ms. Li et al.'s CMU tables use the
    same (frame_ms = 40) although that data is probably at 30 Hz (protocol §1.5)."""
    if frame_ms <= 0 or num_frames < 1:
        raise MetricInputError(
            f"frame_ms must be > 0 and num_frames >= 1, got {frame_ms} and {num_frames}"
        )
    out = {}
    for ms in HORIZONS_MS:
        steps = ms / frame_ms
        if abs(steps - round(steps)) > 1e-6:
            raise MetricInputError(
                f"horizon {ms} ms is not a whole number of {frame_ms} ms frames; the published "
                "tables label frames at 40 ms (use frame_ms=40, also for CMU, protocol §4.3)"
            )
        k = round(steps) - 1
        if k < num_frames:
            out[ms] = k
    return out


def _check_frames(x: Tensor, name: str) -> None:
    if not isinstance(x, Tensor) or not x.is_floating_point():
        raise MetricInputError(f"{name} must be a floating torch.Tensor of unnormalised exp-maps")
    F = x.shape[-1] if x.dim() else 0
    if F < 6 or F % 3 != 0:
        raise MetricInputError(
            f"{name} has {F} columns; expected 3 root-translation columns plus exp-map triples "
            "(99 for H3.6M, 117 for CMU). Pass unnormalised full frames (normalizer.unnormalize)."
        )


def expmap_frames_to_euler(x: Tensor) -> Tensor:
    """Full exp-map frames (..., F) to Euler frames (..., F) as the metric sees them: triples
    from column 3 on converted (protocol §4.1 step 2, as in [M]), columns 0-5, the global
    translation and rotation, set to 0 (step 3)."""
    _check_frames(x, "frames")
    euler = expmap_to_euler(x[..., 3:].unflatten(-1, (-1, 3))).flatten(-2)
    return torch.cat((torch.zeros_like(x[..., :6]), euler[..., 3:]), -1)


def selected_dims(
    gt_euler: Tensor, dim_rule: str = "future", observed_euler: Tensor | None = None
) -> Tensor:
    """Bool mask (B, F) of the Euler dims the error uses in each window (protocol §4.1 step 4):
    those whose ground-truth population std over time is > 1e-4, over the future frames
    gt_euler (B, T, F) ("future", [M]) or observed_euler (B, T_obs, F) + future ("window", [L])."""
    if dim_rule not in DIM_RULES:
        raise MetricInputError(f"dim_rule must be one of {DIM_RULES}, got {dim_rule!r}")
    if dim_rule == "future":
        if gt_euler.shape[1] < 2:
            raise MetricInputError(
                "dim_rule='future' needs at least 2 future frames (the std over one frame is 0, "
                "so no dim would be kept); predict more frames or use dim_rule='window'"
            )
        reference = gt_euler
    else:
        shape = None if observed_euler is None else tuple(observed_euler.shape)
        if shape is None or len(shape) != 3 or shape[::2] != tuple(gt_euler.shape[::2]):
            raise MetricInputError(
                f"dim_rule='window' needs gt_observed_full (B, T_obs, F) = ({gt_euler.shape[0]}, "
                f"T_obs, {gt_euler.shape[2]}), got {shape}"
            )
        reference = torch.cat((observed_euler.to(gt_euler), gt_euler), 1)
    return reference.std(dim=1, correction=0) > STD_THRESHOLD


def euler_error_per_frame(
    pred_full: Tensor,
    gt_full: Tensor,
    dim_rule: str = "future",
    gt_observed_full: Tensor | None = None,
) -> Tensor:
    """Per-window, per-frame Euler error (B, T) in float64 (protocol §4.1 steps 1-5) of
    unnormalised exp-map pred_full and gt_full (B, T, F): the L2 norm of the Euler difference,
    angles unwrapped as in the reference, over the dims selected_dims keeps by dim_rule,
    "future" ([M] after its PR #17 fix) or "window" ([L], needs gt_observed_full (B, T_obs, F))."""
    _check_frames(pred_full, "pred_full")
    _check_frames(gt_full, "gt_full")
    if pred_full.dim() != 3 or pred_full.shape != gt_full.shape:
        raise MetricInputError(
            f"pred_full and gt_full must both be (B, T, F); got {tuple(pred_full.shape)} and "
            f"{tuple(gt_full.shape)}"
        )
    observed = None
    if dim_rule == "window" and gt_observed_full is not None:
        _check_frames(gt_observed_full, "gt_observed_full")
        observed = expmap_frames_to_euler(gt_observed_full.to(gt_full.device).double())

    pred = expmap_frames_to_euler(pred_full.double())
    gt = expmap_frames_to_euler(gt_full.double())
    keep = selected_dims(gt, dim_rule, observed)
    sq = (gt - pred).square() * keep.unsqueeze(1)
    return sq.sum(-1).sqrt()


class PerActionMean(torchmetrics.Metric):
    """Mean of a per-window, per-frame error (B, T) per action and frame, (A, T), over all windows
    seen; NaN for actions without any, which callers show as absent. The states are sums, so the
    value is the same however the windows are split into batches or processes."""

    full_state_update = False
    is_differentiable = False
    higher_is_better = False

    def __init__(self, num_actions: int, num_frames: int, **kwargs):
        super().__init__(**kwargs)
        self.num_actions, self.num_frames = num_actions, num_frames
        zeros = torch.zeros(num_actions, num_frames, dtype=torch.float64)
        self.add_state("error_sum", default=zeros, dist_reduce_fx="sum")
        self.add_state("count", torch.zeros(num_actions, dtype=torch.long), dist_reduce_fx="sum")

    def add(self, err: Tensor, action: Tensor) -> None:
        """Add the errors (B, T) of windows of the actions ``action`` (B,) long."""
        if err.shape[1] != self.num_frames:
            raise MetricInputError(
                f"expected (B, {self.num_frames}, F) predictions, got {err.shape[1]} frames; "
                "num_frames of the metric must equal the number of predicted frames"
            )
        if not isinstance(action, Tensor) or action.dtype not in (torch.int32, torch.int64):
            raise MetricInputError("action must be an integer tensor (B,) of action indices")
        if action.shape != err.shape[:1]:
            raise MetricInputError(
                f"action must have shape ({len(err)},), got {tuple(action.shape)}"
            )
        if len(action) and (action.min() < 0 or action.max() >= self.num_actions):
            raise MetricInputError(
                f"action indices must lie in [0, {self.num_actions}), got "
                f"{action.min()}..{action.max()}"
            )
        action = action.long().to(self.count.device)
        self.error_sum.index_add_(0, action, err.to(self.error_sum.device))
        self.count += torch.bincount(action, minlength=self.num_actions)

    def compute(self) -> Tensor:
        mean = self.error_sum / self.count.clamp_min(1).unsqueeze(1)
        return torch.where(self.count.unsqueeze(1) > 0, mean, torch.nan)


class EulerAngleError(PerActionMean):
    """Mean Euler error (protocol §4.1) per action and future frame, (A, T)."""

    def __init__(self, num_actions: int, num_frames: int, dim_rule: str = "future", **kwargs):
        super().__init__(num_actions, num_frames, **kwargs)
        if dim_rule not in DIM_RULES:
            raise MetricInputError(f"dim_rule must be one of {DIM_RULES}, got {dim_rule!r}")
        self.dim_rule = dim_rule

    def update(
        self,
        pred_full: Tensor,
        gt_full: Tensor,
        action: Tensor,
        gt_observed_full: Tensor | None = None,
    ) -> None:
        self.add(euler_error_per_frame(pred_full, gt_full, self.dim_rule, gt_observed_full), action)
