"""One number for one question (issue 53, point 5). Where an evaluated action has no training
files in the data copy (CMU washwindow in ours), the results page's verdict judges the average
over the other, trained, actions: the validation's TensorBoard curves, its log line and src.eval's
table then also give that average, each under a label naming its set, and it is one number in
all of them. Without such an action, nothing changes."""

from statistics import mean

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.plugins.custom_scalar import layout_pb2

from src.data.synthetic import write_synthetic_h36m
from src.eval import evaluate
from src.prepare import compose_config
from src.train import train

# The synthetic files read as an H3.6M copy (data=synthetic would write any dropped file anew).
DATA = ["data=h36m", "data.actions=[walking,eating,smoking]", "data.train_subjects=[1]"]
TINY = ["model=gru_s2s", "model.net.hidden=16", "trainer=cpu", "iterations=4", "val_every=2"]
QUICK = ["media_every=0", "checkpoint_every=0", "paths.allow_partial=true"]
SMOKING_TRAINING = ["h3.6m/dataset/S1/smoking_1.txt", "h3.6m/dataset/S1/smoking_2.txt"]


def _last(events, tag: str) -> float:
    return events.Scalars(tag)[-1].value


def _chart_titles(events) -> set[str]:
    (config,) = events.Tensors("custom_scalars__config__")
    layout = layout_pb2.Layout.FromString(config.tensor_proto.string_val[0])
    return {chart.title for category in layout.category for chart in category.chart}


@pytest.mark.parametrize("gone", [SMOKING_TRAINING, []], ids=["smoking untrained", "all trained"])
def test_the_trained_actions_average_is_one_number_under_one_label(tmp_path, caplog, gone):
    data_dir = tmp_path / "data"
    write_synthetic_h36m(data_dir)
    for relpath in gone:
        (data_dir / relpath).unlink()
    run = tmp_path / "run"
    with caplog.at_level("INFO", logger="src.lit.checkpoints"):
        train(compose_config("train", [*DATA, *TINY, *QUICK], run, data_dir))
    eval_cfg = [f"ckpt_path={run}/checkpoints/last.ckpt"]
    result = evaluate(compose_config("eval", eval_cfg, tmp_path / "eval", data_dir))
    events = EventAccumulator(str(run / "tensorboard"), size_guidance={"tensors": 0}).Reload()
    tags = events.Tags()["scalars"]
    (line,) = [r.getMessage() for r in caplog.records if "validation at iteration 4" in r.msg]
    markdown = (tmp_path / "eval" / "results.md").read_text()

    if not gone:
        assert not [t for t in tags if "average_trained" in t]
        assert all(t["average_trained"] is None for t in result["tables"])
        assert "**average**" in markdown and "trained actions" not in markdown
        assert line.startswith("validation at iteration 4: Euler error 80 ms ")
        assert "trained" not in line and "average" in _chart_titles(events)
        return

    trained = ["walking", "eating"]
    for table in result["tables"]:  # Euler, MPJPE
        metric, average = table["metric"], table["average_trained"]
        assert table["untrained_actions"] == ["smoking"] and average["actions"] == trained
        assert table["average"]["actions"] == [*trained, "smoking"]  # the key others read
        tolerance = {"abs": 1e-6} if metric == "euler" else {"rel": 1e-6}  # MPJPE in mm
        for ms in table["horizons_ms"]:
            logged = _last(events, f"val_{metric}/average_trained/{ms:04d}ms")
            evaluated = average["values"][str(ms)]
            per_action = mean(table["values"][a][str(ms)] for a in trained)
            assert logged == pytest.approx(evaluated, **tolerance)
            assert evaluated == pytest.approx(per_action, abs=1e-12)
            # The plain average, under its old tag, is still over all 3 evaluated actions.
            every = _last(events, f"val_{metric}/average/{ms:04d}ms")
            assert every == pytest.approx(table["average"]["values"][str(ms)], **tolerance)
        assert average["values"] != table["average"]["values"]  # else the check shows nothing

    labels = {"all 3 evaluated actions", "2 trained actions"}
    assert {f"average ({words})" for words in labels} <= _chart_titles(events)
    assert all(f"**average ({words})**" in markdown for words in labels)
    assert "Euler error over all 3 evaluated actions: 80 ms " in line
    assert "; over 2 trained actions: 80 ms " in line
