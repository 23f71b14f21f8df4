"""The validation curve of a run (its TensorBoard's average Euler error at each validation):
read back from the events src.train writes, kept in a run's record, and drawn in the validation
figure beside the published value, so that a reader sees whether a miss is one checkpoint's or
the whole run's. The slow check that the logger's steps are the
iterations is in tests/test_train.py::test_short_run_checkpoints_logs_and_evaluates."""

import pytest

from src.reporting.frame import Results
from src.reporting.groups import group_runs
from src.reporting.published import published_for
from src.reporting.runs import read_records, validation_curve, write_record
from src.reporting.tables import same_set_average
from tests.test_report import ABSENT
from tests.test_report_headline import EVALUATED, seeded


def validation_means(runs) -> dict:
    results = Results(group_runs(runs))
    return results.validation_means(results.groups[0], "srnn")


def test_the_curve_is_the_average_per_horizon_at_each_validation(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    assert validation_curve(tmp_path) == {}  # no tensorboard folder: no curve
    writer = SummaryWriter(str(tmp_path / "tensorboard"))
    for step, value in ((499, 1.5), (999, 1.25)):
        writer.add_scalar("val_euler/average/0080ms", value / 4, step)
        writer.add_scalar("val_euler/average/1000ms", value, step)
        writer.add_scalar("val_euler/walking/1000ms", 9.0, step)  # one action, not the average
        writer.add_scalar("val/euler_avg", 9.0, step)
        writer.add_scalar("val_mpjpe/average/1000ms", 9.0, step)
    writer.add_scalar("train/loss_d", 9.0, 700)
    writer.close()
    assert validation_curve(tmp_path) == {
        500: {80: 0.375, 1000: 1.5},
        1000: {80: 0.3125, 1000: 1.25},
    }


def with_curve(run: dict, curve: dict[int, float]) -> dict:
    run["validations"] = {i: {80: 0.4, 1000: v} for i, v in curve.items()}
    return run


def test_runs_of_one_seed_count_once_with_the_kept_runs_own_curve():
    """A resume continues in its run's folder, curve included: nothing is joined."""
    first = with_curve(seeded(0.0, 1), {500: 1.9, 1000: 1.8})
    first.update(folder="/o/t1", iterations=1200)
    last = with_curve(seeded(0.0, 1), {500: 1.9, 1000: 1.8, 1500: 1.7, 2000: 1.6})
    last.update(folder="/o/t2", iterations=2000)
    (group,) = group_runs([first, last])
    assert group.runs == [last] and len(group.left_out) == 1
    assert {i: e[1000] for i, e in last["validations"].items()} == {
        500: 1.9,
        1000: 1.8,
        1500: 1.7,
        2000: 1.6,
    }


def validation_lines(runs) -> dict[str, list[float]]:
    """{label: y values} of the validation figure's lines."""
    from src.reporting.headline import figures

    for run in runs:  # the figure draws 400 and 1000 ms, as src.train logs every horizon
        for errors in run["validations"].values():
            errors.setdefault(400, 1.2)
    _, figure = figures(Results(group_runs(runs)), "srnn")
    return {line.get_label(): list(line.get_ydata()) for line in figure.axes[0].get_lines()}


def test_the_validation_figure_draws_the_seeds_mean_beside_the_published_value():
    published, _ = published_for({"paper": "li2018", "method": "conv_s2s"}, "h36m")
    at_1000 = same_set_average(published, EVALUATED, [1000])[1000]
    # Seed 3 also validated at 1,500: only the validations every seed made are averaged.
    runs = [
        with_curve(seeded(0.05, 1), {500: 1.80, 1000: 1.76}),
        with_curve(seeded(0.05, 2), {500: 1.90, 1000: 1.74}),
        with_curve(seeded(0.05, 3), {500: 1.70, 1000: 1.72, 1500: 9.0}),
    ]
    assert list(validation_means(runs)) == [500, 1000]
    lines = validation_lines(runs)
    ours = lines["1000 ms, 4,000 iterations, mean of 3 seeds"]
    assert ours == pytest.approx([1.80, 1.74])
    assert lines["1000 ms, published"] == pytest.approx([at_1000, at_1000])
    # Without curves (a run logged elsewhere, an older record) there is nothing to draw.
    for run in runs:
        run["validations"] = {}
    assert validation_means(runs) == {}


def test_one_validation_of_one_seed():
    assert validation_means([with_curve(seeded(0.05, 1), {500: 1.8})]) == {
        500: {80: 0.4, 1000: 1.8}
    }


def test_a_curve_validated_on_another_protocol_is_not_shown():
    run = with_curve(seeded(0.05, 1), {500: 1.8})
    run["config"]["data"]["eval_protocol"] = "random"
    assert validation_means([run]) == {}


def test_a_record_keeps_the_curve_with_its_numbers_as_numbers(tmp_path):
    run = with_curve(seeded(0.0, 1, absent=ABSENT), {500: 1.8, 1000: 1.75})
    write_record(run, tmp_path, "abc", "2026-01-01")
    (again,) = read_records(tmp_path, ["srnn"])
    assert again["validations"] == {500: {80: 0.4, 1000: 1.8}, 1000: {80: 0.4, 1000: 1.75}}


@pytest.mark.parametrize("curve", [{}, None])
def test_a_record_without_a_curve_reads_as_none(tmp_path, curve):
    run = seeded(0.0, 1)
    if curve is not None:
        run["validations"] = curve
    write_record(run, tmp_path, "abc", "2026-01-01")
    (again,) = read_records(tmp_path, ["srnn"])
    assert not again.get("validations")


def test_the_curve_of_a_row_with_an_untrained_action_is_compared_over_the_same_actions():
    """The validations average every evaluated action, CMU washwindow too, though the verdict
    judges the actions with training files: the published value beside the curve is the one
    over the curve's own actions (it was the judged set's)."""
    from src.data.layout import cmu_files
    from tests.test_report import offset_run

    run = with_curve(offset_run(0.08, "li2018_cmu", "cmu", absent={}), {2000: 1.6, 4000: 1.5})
    run["train_missing_files"] = [e.relpath for e in cmu_files(["washwindow"], "train")]
    published, _ = published_for({"paper": "li2018", "method": "conv_s2s"}, "cmu")
    evaluated = [a for a in published if a != "average"]
    every = same_set_average(published, evaluated, [1000])[1000]
    judged = same_set_average(published, [a for a in evaluated if a != "washwindow"], [1000])
    assert f"{every:.2f}" != f"{judged[1000]:.2f}"  # else the test could not tell them apart
    assert validation_lines([run])["1000 ms, published"] == pytest.approx([every, every])
