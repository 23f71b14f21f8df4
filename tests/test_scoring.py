"""Scoring any model under the papers' protocol (issue #25): `python -m src.export_windows`
writes the protocol's test windows, `python -m src.eval predictions=...` scores a file of
predictions made from them by any code, with the tables src.eval prints for its own models."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest

from src.config import ConfigError
from src.data.synthetic import synthetic_motion
from src.data.windows import srnn_h36m_starts
from src.scoring import PredictionsError, windows_sha256
from tests.conftest import compose_config, run_module


def _export(tmp_path, data_dir, *overrides: str) -> dict[str, np.ndarray]:
    from src.export_windows import export

    out = tmp_path / f"windows_{len(list(tmp_path.glob('windows_*')))}.npz"
    cfg = compose_config(
        "export_windows", ["data=synthetic", f"out={out}", *overrides], tmp_path / "x", data_dir
    )
    with contextlib.redirect_stdout(io.StringIO()):
        export(cfg)
    with np.load(out) as npz:
        return dict(npz)


def _evaluate(tmp_path, data_dir, *overrides: str) -> tuple[dict, str]:
    """(results, printed tables) of src.eval, in-process; the printed text without its last
    line, which names the run folder."""
    from src.eval import evaluate

    folder = tmp_path / f"eval_{len(list(tmp_path.glob('eval_*')))}"
    cfg = compose_config(
        "eval", ["trainer=cpu", "trainer.enable_progress_bar=false", *overrides], folder, data_dir
    )
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        result = evaluate(cfg)
    text = printed.getvalue()
    assert text.rstrip().splitlines()[-1] == f"written to {folder}"
    return result, text.rstrip().rsplit("\n", 1)[0]


def _assert_same_values(result: dict, reference: dict) -> None:
    """Every cell of every table equal to float32 rounding, and the same actions absent."""
    for table, expected in zip(result["tables"], reference["tables"], strict=True):
        assert table["absent"] == expected["absent"]
        assert table["values"].keys() == expected["values"].keys()
        for action, row in expected["values"].items():
            assert table["values"][action] == pytest.approx(row, rel=1e-6)


def _zero_velocity(windows: dict, **extra) -> dict[str, np.ndarray]:
    """Zero-velocity made with numpy from the exported observed frames alone."""
    T = windows["future"].shape[1]
    prediction = np.repeat(windows["observed"][:, -1:], T, axis=1)
    return {"prediction": prediction, "window_id": windows["window_id"], **extra}


def _save(tmp_path, arrays: dict, name: str = "preds.npz"):
    path = tmp_path / name
    np.savez(path, **arrays)
    return path


@pytest.fixture(scope="module")
def srnn_windows(tmp_path_factory, synthetic_data_dir):
    return _export(tmp_path_factory.mktemp("export"), synthetic_data_dir)


# ------------------------------------------------------------------------------ export
def test_export_writes_the_srnn_windows_as_raw_frames(srnn_windows):
    """Checked against the protocol's definition, not against the export's own code path: the
    SRNN starts of §3.1 on the 200-frame synthetic test files, and the frames the generator
    wrote for subject 5 (every second raw frame, §1.3)."""
    w = srnn_windows
    assert w["observed"].shape == (24, 50, 99) and w["future"].shape == (24, 25, 99)
    assert w["observed"].dtype == np.float32
    assert (str(w["dataset"]), str(w["protocol"]), float(w["fps"])) == ("synthetic", "srnn", 25.0)
    row = 0
    for action in ("walking", "eating", "smoking"):
        for sub, start in srnn_h36m_starts(200, 200):
            assert w["window_id"][row] == f"S5/{action}_{sub}@{start}"
            assert w["action"][row] == action
            raw = synthetic_motion(5, action, sub, 400)[::2][start : start + 75]
            frames = np.concatenate([w["observed"][row], w["future"][row]])
            np.testing.assert_allclose(frames, raw, atol=1e-6)
            row += 1
    assert str(w["data_sha256"]) == windows_sha256(
        w["window_id"], np.concatenate([w["observed"], w["future"]], axis=1)
    )


def test_random_protocol_names_each_repeat_of_a_window(tmp_path, synthetic_data_dir):
    """256 draws per action from 2 x 109 possible starts repeat windows: each repeat gets its
    own id (`#2`, `#3`), so ids stay unique and name the same frames."""
    w = _export(tmp_path, synthetic_data_dir, "protocol=random")
    ids = list(w["window_id"])
    assert len(ids) == 3 * 256 and len(set(ids)) == len(ids)
    repeats = [i for i, name in enumerate(ids) if "#" in name]
    assert repeats
    for i in repeats:
        first = ids.index(ids[i].split("#")[0])
        np.testing.assert_array_equal(w["observed"][i], w["observed"][first])


def test_export_never_writes_over_a_file(tmp_path, synthetic_data_dir):
    from src.export_windows import export

    out = tmp_path / "windows.npz"
    out.write_bytes(b"mine")
    cfg = compose_config(
        "export_windows", ["data=synthetic", f"out={out}"], tmp_path / "x", synthetic_data_dir
    )
    with pytest.raises(ConfigError, match="already exists; nothing was overwritten"):
        export(cfg)
    assert out.read_bytes() == b"mine"


# ------------------------------------------------------------------------------ scoring
@pytest.mark.parametrize("protocol", ["srnn", "random"])
def test_numpy_zero_velocity_scores_exactly_as_the_baseline(protocol, tmp_path, synthetic_data_dir):
    """Rows shuffled: matched by id, in any order. The random protocol's repeated windows
    count once per draw, as src.eval counts them."""
    windows = _export(tmp_path, synthetic_data_dir, f"protocol={protocol}")
    arrays = _zero_velocity(windows, model=np.array("zero_velocity"))
    order = np.random.default_rng(0).permutation(len(arrays["window_id"]))
    path = _save(tmp_path, {k: v[order] if v.ndim else v for k, v in arrays.items()})
    ours, ours_text = _evaluate(
        tmp_path,
        synthetic_data_dir,
        f"predictions={path}",
        "data=synthetic",
        f"protocol={protocol}",
    )
    base, base_text = _evaluate(
        tmp_path,
        synthetic_data_dir,
        "model=zero_velocity",
        "data=synthetic",
        f"protocol={protocol}",
    )
    assert ours_text == base_text
    # Beyond the printed digits, to float32 rounding: numpy's last observed frame is not bit for
    # bit the baseline's, which went through normalisation and back.
    _assert_same_values(ours, base)
    assert ours["provenance"]["predictions"] == str(path)


def test_export_predict_score_equals_eval_of_the_checkpoint(tmp_path, synthetic_data_dir):
    """The issue's agreement: windows exported, predicted through MotionForecaster from a
    trained checkpoint (a GRU that takes the action label), scored: the same printed tables
    as `src.eval ckpt_path=`."""
    from src.inference import MotionForecaster
    from src.train import train

    cfg = compose_config(
        "train",
        ["data=synthetic", "trainer=cpu", "iterations=2", "val_every=2", "model=gru_s2s"]
        + ["model.net.hidden=16"],
        tmp_path / "run",
        synthetic_data_dir,
    )
    train(cfg)
    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    windows = _export(tmp_path, synthetic_data_dir)
    forecaster = MotionForecaster.from_checkpoint(ckpt)
    prediction = np.empty_like(windows["future"])
    for action in ("walking", "eating", "smoking"):
        rows = windows["action"] == action
        prediction[rows] = forecaster.predict(windows["observed"][rows], action=action)
    path = _save(
        tmp_path,
        {"prediction": prediction, "window_id": windows["window_id"], "model": np.array("gru_s2s")},
    )
    scored, scored_text = _evaluate(
        tmp_path, synthetic_data_dir, f"predictions={path}", "data=synthetic"
    )
    evaluated, evaluated_text = _evaluate(tmp_path, synthetic_data_dir, f"ckpt_path={ckpt}")
    assert "gru_s2s on synthetic (srnn protocol, 24 windows)" in scored_text
    assert scored_text == evaluated_text
    # The values too, to float rounding: src.eval predicts all 24 windows in one batch, here
    # each action's 8 (the action label is the forecaster's argument), and a batch of another
    # size may round differently (bit for bit equal on the machine this was written on).
    _assert_same_values(scored, evaluated)
    # Not vacuous: the trained GRU is not zero-velocity.
    assert not np.allclose(prediction, np.repeat(windows["observed"][:, -1:], 25, axis=1))


def test_a_subset_of_actions_is_scored_and_the_rest_named_absent(
    srnn_windows, tmp_path, synthetic_data_dir
):
    full = _zero_velocity(srnn_windows)
    rows = srnn_windows["action"] == "walking"
    path = _save(tmp_path, {k: v[rows] for k, v in full.items()}, "walking_only.npz")
    result, text = _evaluate(tmp_path, synthetic_data_dir, f"predictions={path}", "data=synthetic")
    whole, _ = _evaluate(
        tmp_path, synthetic_data_dir, f"predictions={_save(tmp_path, full)}", "data=synthetic"
    )
    for table, reference in zip(result["tables"], whole["tables"], strict=True):
        assert table["values"] == {"walking": reference["values"]["walking"]}
        assert table["absent"] == {
            "eating": "no predictions in walking_only.npz",
            "smoking": "no predictions in walking_only.npz",
        }
    assert "(srnn protocol, 8 windows)" in text and result["provenance"]["windows"] == 8
    assert "absent (eating, smoking): no predictions in walking_only.npz" in text


def test_columns_the_protocol_ignores_do_not_count(srnn_windows, tmp_path, synthetic_data_dir):
    """The 45 columns constant in the training data are set to their training mean, as
    unnormalising a network's output does; the used ones are scored as given."""
    from src.data.synthetic import H36M_USED_COLUMNS

    plain = _zero_velocity(srnn_windows)
    ignored = np.setdiff1d(np.arange(99), H36M_USED_COLUMNS)
    noisy = {**plain, "prediction": plain["prediction"].copy()}
    noisy["prediction"][..., ignored] = np.random.default_rng(0).normal(size=(24, 25, 45))
    used_moved = {**plain, "prediction": plain["prediction"] + 0.1}
    results = [
        _evaluate(tmp_path, synthetic_data_dir, f"predictions={path}", "data=synthetic")[0]
        for path in (
            _save(tmp_path, plain, "plain.npz"),
            _save(tmp_path, noisy, "noisy.npz"),
            _save(tmp_path, used_moved, "moved.npz"),
        )
    ]
    values = [[table["values"] for table in result["tables"]] for result in results]
    assert values[1] == values[0]  # bit for bit
    assert values[2][0] != values[0][0]


def test_plot_errors_and_the_report_take_the_scored_results(
    srnn_windows, tmp_path, synthetic_data_dir, capsys
):
    from src.plot_errors import plot_errors
    from src.report import main as report
    from tests.conftest import compose_config

    path = _save(tmp_path, _zero_velocity(srnn_windows, model=np.array("my_model")))
    result, _ = _evaluate(tmp_path, synthetic_data_dir, f"predictions={path}", "data=synthetic")
    (results_json,) = tmp_path.glob("eval_*/results.json")
    assert plot_errors([results_json], tmp_path / "errors.png").is_file()
    page = tmp_path / "results.md"
    common = [f"out={page}", "datasets=[]", f"scored=[{results_json}]"]
    assert report(compose_config("report", [*common, "protocols=[srnn]"], tmp_path / "w")) == 0
    rows = [
        [c.strip() for c in line.strip("|").split("|")]
        for line in page.read_text().splitlines()
        if line.startswith("| my_model")
    ]
    average = result["tables"][0]["average"]["values"]
    cells = [f"{average[str(ms)]:.2f}" for ms in (80, 160, 320, 400, 560, 1000)]
    assert ["my_model", "synthetic", "-", "-", "-", *cells] in rows
    assert any(row[0] == "my_model (predictions)" for row in rows)
    with pytest.raises(SystemExit):
        report(compose_config("report", [*common, "protocols=[srnn,random]"], tmp_path / "w2"))
    assert "has no results for protocol random: score its" in capsys.readouterr().err


def test_published_values_stand_beside_a_file_on_a_papers_dataset():
    """On H3.6M and CMU the chosen paper's values stand beside ours (src.eval's tables take
    them from `published`); a paper and method without numbers there is refused."""
    from src.scoring import published_ref

    assert published_ref("li2018:conv_s2s", "h36m") == {"paper": "li2018", "method": "conv_s2s"}
    assert published_ref("li2018:conv_s2s", "cmu") == {"paper": "li2018", "method": "conv_s2s"}
    assert published_ref("none", "h36m") is None
    with pytest.raises(ConfigError, match="no published cmu numbers of that paper and method"):
        published_ref("martinez2017:residual_sup_ma", "cmu")
    with pytest.raises(ConfigError, match="PAPER:METHOD"):
        published_ref("conv_s2s", "h36m")


# ------------------------------------------------------------------------------ bad input
def _bad_files(w: dict) -> dict[str, tuple[object, str]]:
    """case -> (arrays to save, or bytes for a file that is no .npz; expected message)."""
    good = _zero_velocity(w)
    pred, ids = good["prediction"], good["window_id"]
    first = str(ids[0])
    moved_ids = np.array([i.replace("@", "@1") for i in ids])  # starts no srnn window has
    walking = w["action"] == "walking"
    return {
        "not_npz": (b"prediction,window_id\n", "is not a .npz file numpy can read"),
        "one_array": ("npy", "holds one array, not a .npz of named arrays"),
        "no_window_id": ({"prediction": pred}, "has no window_id array (it holds: prediction)"),
        "no_arrays": ({"preds": pred}, "has no prediction and no window_id array"),
        "object_ids": (
            {"prediction": pred, "window_id": np.array(list(ids), dtype=object)},
            "window_id is an array of Python objects",
        ),
        "text_prediction": (
            {"prediction": pred.astype(str), "window_id": ids},
            "it must hold numbers",
        ),
        "not_3d": (
            {"prediction": pred.reshape(len(ids), -1), "window_id": ids},
            "must be (N, T, F)",
        ),
        "ids_2d": (
            {"prediction": pred, "window_id": ids[:, None]},
            "must be a 1-D array of strings",
        ),
        "count": ({"prediction": pred, "window_id": ids[:-1]}, "23 window ids for 24 predictions"),
        "nan": (
            {"prediction": np.where(np.arange(99) == 7, np.nan, pred), "window_id": ids},
            f"NaN or inf value(s), the first in window {first!r} (row 0), frame 0, column 7",
        ),
        "cmu_columns": (
            {"prediction": np.zeros((24, 25, 117)), "window_id": ids},
            "prediction has 117 columns per frame, synthetic frames have 99: a file for cmu? "
            "score it with data=cmu",
        ),
        "normalised_columns": (
            {"prediction": np.zeros((24, 25, 54)), "window_id": ids},
            "54 is the number of normalised columns",
        ),
        "short_horizon": (
            {"prediction": pred[:, :10], "window_id": ids},
            "has 10 frames per window, and the table's 560 ms column needs 14: predict 25 "
            "frames (data.future_len), or score fewer horizons with data.future_len=10",
        ),
        "long_horizon": (
            {"prediction": np.concatenate([pred, pred], 1), "window_id": ids},
            "save the first 25, prediction[:, :25]",
        ),
        "duplicate_ids": (
            {"prediction": pred, "window_id": np.array([ids[0], *ids[:-1]])},
            f"window_id {first!r} appears 2 times",
        ),
        "unknown_ids": (
            {"prediction": pred, "window_id": np.array([*ids[:-1], "S5/walking_3@20"])},
            "1 of 24 window ids are not synthetic protocol=srnn test windows (e.g. "
            "'S5/walking_3@20')",
        ),
        "missing_ids": (
            {"prediction": pred[1:], "window_id": ids[1:]},
            f"1 of the 8 walking windows have no prediction (e.g. {first!r}); predict all of "
            "them, or none to leave walking out",
        ),
        "other_protocol_ids": (
            {"prediction": pred, "window_id": moved_ids},
            "a file for another protocol, dataset or data.future_len? Predict the windows of "
            "`python -m src.export_windows data=synthetic protocol=srnn`",
        ),
        "protocol_entry": (
            {**good, "protocol": np.array("random")},
            "holds predictions for protocol random (its 'protocol' entry), not srnn: score it "
            "with protocol=random",
        ),
        "dataset_entry": (
            {**good, "dataset": np.array("h36m")},
            "holds predictions for dataset h36m (its 'dataset' entry), not synthetic: score it "
            "with data=h36m",
        ),
        "checksum": (
            {**good, "data_sha256": np.array("0" * 64)},
            "its data_sha256 is not that of the windows here",
        ),
        "no_rows": (
            {"prediction": pred[walking][:0], "window_id": ids[walking][:0]},
            "it must be (N, T, F) with N >= 1",
        ),
    }


# The case names, from stand-in windows (the real ones come from a fixture).
CASES = sorted(
    _bad_files(
        {
            "observed": np.zeros((24, 50, 99)),
            "future": np.zeros((24, 25, 99)),
            "window_id": np.array(["S5/walking_1@16"] * 24),
            "action": np.array(["walking"] * 24),
        }
    )
)


@pytest.mark.parametrize("case", CASES)
def test_each_bad_predictions_file_is_one_line_naming_the_fix(
    case, srnn_windows, tmp_path, synthetic_data_dir
):
    content, message = _bad_files(srnn_windows)[case]
    path = tmp_path / "preds.npz"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content == "npy":
        with path.open("wb") as fh:
            np.save(fh, srnn_windows["observed"])
    else:
        np.savez(path, **content)
    with pytest.raises(PredictionsError) as info:
        _evaluate(tmp_path, synthetic_data_dir, f"predictions={path}", "data=synthetic")
    text = str(info.value)
    assert "\n" not in text
    assert message in text, text


@pytest.mark.parametrize(
    ("layout", "axes"),
    [("windows, columns, frames", (0, 2, 1)), ("frames, windows, columns", (1, 0, 2))],
)
def test_a_transposed_prediction_is_named_transposed(
    layout, axes, srnn_windows, tmp_path, synthetic_data_dir
):
    """It was blamed on window_id (24 ids for 25 predictions) or on its number of columns."""
    good = _zero_velocity(srnn_windows)
    prediction = good["prediction"].transpose(axes)  # its own inverse, both of these
    path = _save(tmp_path, {**good, "prediction": prediction})
    with pytest.raises(PredictionsError) as info:
        _evaluate(tmp_path, synthetic_data_dir, f"predictions={path}", "data=synthetic")
    text = str(info.value)
    assert str(path) in text and "transposed" in text and "window_id" not in text, text
    assert str(prediction.shape) in text and "(24, 25, 99)" in text, text  # found, expected
    assert f"transpose{axes}" in text, text  # the fix, which gives back the expected shape


def test_a_prediction_in_degrees_is_refused_naming_the_unit_and_the_fix(
    srnn_windows, tmp_path, synthetic_data_dir
):
    """Degrees were scored as radians without a word (about 10 rad at every horizon on
    H3.6M). Exp-map angles of real motion stay within pi (at most 3.1416 in every frame of
    the real archives); the root position, columns 0-2, is no angle and may be of any size."""
    good = _zero_velocity(srnn_windows)
    path = _save(tmp_path, {**good, "prediction": np.rad2deg(good["prediction"])}, "deg.npz")
    with pytest.raises(PredictionsError) as info:
        _evaluate(tmp_path, synthetic_data_dir, f"predictions={path}", "data=synthetic")
    text = str(info.value)
    assert str(path) in text and "\n" not in text
    assert "degrees" in text and "np.deg2rad" in text, text
    edge = good["prediction"].copy()
    edge[..., :3] = 5000.0  # millimetres, say
    edge[..., 6:9] = [np.pi, 0.0, 0.0]  # a used joint at the largest angle radians have
    path = _save(tmp_path, {**good, "prediction": edge}, "edge.npz")
    result, _ = _evaluate(tmp_path, synthetic_data_dir, f"predictions={path}", "data=synthetic")
    assert result["tables"][0]["values"]


def test_missing_file_and_conflicting_settings_are_refused(tmp_path, synthetic_data_dir):
    with pytest.raises(PredictionsError, match="predictions file not found: .*np.savez"):
        _evaluate(tmp_path, synthetic_data_dir, f"predictions={tmp_path}/no.npz", "data=synthetic")
    with pytest.raises(ConfigError, match="say whose test windows .* data=h36m"):
        _evaluate(tmp_path, synthetic_data_dir, f"predictions={tmp_path}/no.npz")
    with pytest.raises(ConfigError, match="drop ckpt_path= and model="):
        _evaluate(
            tmp_path,
            synthetic_data_dir,
            "predictions=p.npz",
            "model=zero_velocity",
            "data=synthetic",
        )


def test_cli_bad_predictions_is_one_line_and_leaves_no_run_folder(tmp_path, synthetic_data_dir):
    path = tmp_path / "preds.npz"
    np.savez(path, prediction=np.zeros((2, 25, 99)))
    proc = run_module(
        "src.eval",
        f"predictions={path}",
        "data=synthetic",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path / "out",
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    (line,) = [x for x in proc.stderr.splitlines() if x.startswith("error:")]
    assert line.startswith(f"error: {path} has no window_id array")
    assert not list((tmp_path / "out").rglob("*.json"))


def test_a_scored_file_gets_a_folder_named_after_it(tmp_path, synthetic_data_dir):
    """The run folder of `src.eval predictions=...` names the file and the data scored (it was
    checkpoint_<data> whatever the file), as a checkpoint's or a baseline's folder does."""
    overrides = [f"predictions={tmp_path}/gru_preds.npz", "data=synthetic"]
    cfg = compose_config("eval", overrides, tmp_path / "out", synthetic_data_dir)
    assert cfg.run_name == "predictions_gru_preds_synthetic"
    assert f"{tmp_path}/out/eval/runs/predictions_gru_preds_synthetic/" in cfg.hydra.run.dir


def test_help_of_both_commands_names_their_options(help_text):
    texts = {entry: help_text(entry) for entry in ("src.export_windows", "src.eval")}
    for option in ("data: cmu, h36m, synthetic", "protocol=srnn|random|strided", "out=PATH.npz"):
        assert option in texts["src.export_windows"]
    for option in ("predictions=FILE.npz", "published=PAPER:METHOD", "protocol=srnn|"):
        assert option in texts["src.eval"]


# ------------------------------------------------------------------------------ real data
@pytest.mark.realdata
def test_numpy_zero_velocity_on_exported_srnn_windows_gives_martinez_table1(
    archives, real_data_dir, tmp_path
):
    """Martinez et al. 2017, Table 1, zero-velocity: from the exported windows and numpy alone."""
    from src.export_windows import export

    out = tmp_path / "windows.npz"
    overrides = ["data=h36m", "data.allow_partial=true", f"paths.archive_dir={archives}"]
    cfg = compose_config(
        "export_windows", [*overrides, f"out={out}"], tmp_path / "x", real_data_dir
    )
    with contextlib.redirect_stdout(io.StringIO()):
        export(cfg)
    with np.load(out) as windows:
        path = _save(tmp_path, _zero_velocity(dict(windows)))
    result, _ = _evaluate(tmp_path, real_data_dir, f"predictions={path}", *overrides)
    euler = result["tables"][0]
    table1 = {"walking": [0.39, 0.68, 0.99, 1.15], "eating": [0.27, 0.48, 0.73, 0.86]}
    for action, published in table1.items():
        values = euler["values"][action]
        ours = [round(values.get(ms, values.get(str(ms))), 2) for ms in (80, 160, 320, 400)]
        assert ours == published, action
