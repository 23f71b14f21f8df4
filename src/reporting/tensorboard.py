"""The TensorBoard layout src.train writes, and the validation curve src.report reads back."""

from __future__ import annotations

from pathlib import Path

AVERAGE_TAG = "val_euler/average/"


def add_error_curve_layout(writer, actions: list[str], horizons, averages=None) -> None:
    """Custom scalars: a chart per metric and action (and average), a line per horizon.
    `averages`: src.lit.predictor.averages() of the run; a chart's title names its set where
    there are two (the tag stays `average`: validation_curve reads old runs by it)."""
    titles = {n: f"average ({words})" if words else n for n, (_, words) in (averages or {}).items()}
    charts = {"average": "average"} | titles | {a: a for a in actions}
    layout = {
        f"val {m} error per horizon": {
            title: ["Multiline", [f"val_{m}/{tag}/{ms:04d}ms" for ms in horizons]]
            for tag, title in charts.items()
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
