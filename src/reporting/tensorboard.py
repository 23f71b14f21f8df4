"""TensorBoard layout: one chart per action holding the error curves of all its horizons."""

from __future__ import annotations


def error_curve_layout(actions: list[str], horizons: dict[int, int]) -> dict:
    """Custom-scalar layout: for each metric, one multiline chart per action (and the average),
    each with one line per horizon. Tags match MotionPredictor's logging."""
    layout = {}
    for stage in ("val",):
        for metric in ("euler", "mpjpe"):
            charts = {}
            for action in ["average", *actions]:
                tags = [f"{stage}_{metric}/{action}/{ms:04d}ms" for ms in horizons]
                charts[action] = ["Multiline", tags]
            layout[f"{stage} {metric} error per horizon"] = charts
    return layout


def add_error_curve_layout(writer, actions: list[str], horizons: dict[int, int]) -> None:
    writer.add_custom_scalars(error_curve_layout(actions, horizons))
