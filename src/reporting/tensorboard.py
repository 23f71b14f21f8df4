"""The TensorBoard layout src.train writes, and the validation curve src.report reads back."""

from __future__ import annotations

from pathlib import Path

AVERAGE_TAG = "val_euler/average/"


def add_error_curve_layout(writer, actions: list[str], horizons) -> None:
    """Custom scalars: a chart per metric and action (and the average), a line per horizon."""
    layout = {
        f"val {m} error per horizon": {
            a: ["Multiline", [f"val_{m}/{a}/{ms:04d}ms" for ms in horizons]]
            for a in ["average", *actions]
        }
        for m in ("euler", "mpjpe")
    }
    writer.add_custom_scalars(layout)


def validation_curve(run: Path) -> dict[int, dict[int, float]]:
    """{iterations done: {ms: average Euler error}} at each validation, from TensorBoard ({}
    without): logged at the step of the iteration before it (from 0), so after `step + 1`."""
    folder = Path(run) / "tensorboard"
    if not any(folder.glob("events.out.tfevents.*")):
        return {}
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(folder), size_guidance={"scalars": 0}).Reload()
    curve: dict[int, dict[int, float]] = {}
    for tag in events.Tags()["scalars"]:
        if tag.startswith(AVERAGE_TAG) and tag.endswith("ms"):
            ms = int(tag[len(AVERAGE_TAG) : -2])
            for event in events.Scalars(tag):  # a step logged twice: the later value
                curve.setdefault(event.step + 1, {})[ms] = float(event.value)
    return dict(sorted(curve.items()))
