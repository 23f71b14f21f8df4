"""Errors a user can cause become one line naming the problem and the fix; labels and published
numbers tell the truth; every entry point answers --help with its own options (issue #13)."""

from __future__ import annotations

import json
import re
import sys
import zipfile
from pathlib import Path

import hydra
import lightning as L
import pytest
from omegaconf import OmegaConf

from src.config import ConfigError
from src.data.errors import DataError
from tests.conftest import (
    CONF,
    compose_config,
    refused,
    run_in_one_process,
    run_interrupted,
    run_module,
)


def _error_line(proc) -> str:
    """The one `error: ...` line of a command that failed the project's way (status 2)."""
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    (line,) = [x for x in proc.stderr.splitlines() if x.startswith("error:")]
    return line


# ---------------------------------------------------------------- row 5: damaged archive member
def _damaged_h36m_zip(path: Path) -> str:
    """A small h3.6m.zip whose second member has bytes flipped mid-file (stored, so the flip
    lands in the member's data and only the CRC tells); returns that member's name."""
    line = ",".join(["0.1234567"] * 99) + "\n"
    names = ["h3.6m/dataset/S1/walking_1.txt", "h3.6m/dataset/S1/walking_2.txt"]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        for name in names:
            zf.writestr(name, line * 40)
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(names[1])
    raw = bytearray(path.read_bytes())
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    middle = start + info.compress_size // 2
    raw[middle : middle + 8] = bytes(b ^ 0xFF for b in raw[middle : middle + 8])
    path.write_bytes(bytes(raw))
    return names[1]


def test_damaged_archive_member_is_a_data_error_naming_archive_member_and_fix(tmp_path):
    from src.data.archive import unpack_archive

    archive = tmp_path / "h3.6m.zip"
    member = _damaged_h36m_zip(archive)
    data = tmp_path / "data"
    with pytest.raises(DataError) as info:
        unpack_archive(archive, data, "h36m")
    message = str(info.value)
    assert "\n" not in message
    assert str(archive) in message and member in message
    assert "download h3.6m.zip again" in message and "MANIFEST" in message
    assert list(data.iterdir()) == []  # nothing half-unpacked is left


def test_cli_damaged_archive_is_one_line(tmp_path):
    archive = tmp_path / "h3.6m.zip"
    member = _damaged_h36m_zip(archive)
    proc = run_module(
        "src.eval",
        "model=zero_velocity",
        "data=h36m",
        f"data.archive={archive}",
        data_dir=tmp_path / "data",
        log_dir=tmp_path / "out",
    )
    line = _error_line(proc)
    assert member in line and "download h3.6m.zip again" in line


def test_cli_ctrl_c_during_the_first_unpack_is_one_line_and_leaves_no_half_unpacked_data(
    tmp_path,
):
    """Ctrl-C after the archive's first member is written: status 130, one line, no
    traceback (there was one), and no folder the next run could take for the data: it
    unpacks the archive whole."""
    from src.data.archive import ensure_dataset

    archive, data = tmp_path / "h3.6m.zip", tmp_path / "data"
    members = {f"h3.6m/dataset/S1/walking_{i}.txt": ",".join([f"0.{i}"] * 99) for i in (1, 2)}
    with zipfile.ZipFile(archive, "w") as zf:
        for name, line in members.items():
            zf.writestr(name, line + "\n")
    proc = run_interrupted(
        ("zipfile:ZipFile", "open"), 1, "src.eval", "model=zero_velocity", "data=h36m",
        f"data.archive={archive}", data_dir=data, log_dir=tmp_path / "out",
    )  # fmt: skip
    output = proc.stdout + proc.stderr
    assert proc.returncode == 130 and "Traceback" not in output, output[-3000:]
    assert "unpacking" in proc.stdout  # interrupted there, not before
    assert len([x for x in proc.stderr.splitlines() if "Ctrl-C" in x]) == 1, proc.stderr
    assert list(data.iterdir()) == []  # no h3.6m/, no .h3.6m.unpacking-<pid>/
    assert not list((tmp_path / "out").rglob("*.*"))
    ensure_dataset("h36m", data, archive)
    for name, line in members.items():
        assert (data / name).read_text() == line + "\n"


# ------------------------------------------------------------ row 6: nothing to train
def test_cli_training_a_baseline_is_refused_before_anything_is_written(
    tmp_path, synthetic_data_dir
):
    proc = run_module(
        "src.train",
        "model=zero_velocity",
        "data=synthetic",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    refused(
        _error_line(proc), "zero_velocity", "python -m src.eval model=zero_velocity data=synthetic"
    )
    # Nothing of the run's own (Hydra's record of a refused run, .hydra/ and the log, is the
    # business of the run-folder rules, issue #13 row 11).
    written = [p for p in tmp_path.rglob("*") if p.is_file() and ".hydra" not in p.parts]
    assert [p.name for p in written if p.suffix != ".log"] == []


@pytest.mark.parametrize(
    "overrides", [["model=running_avg_2", "adversarial=none"], ["model=running_avg_4"]]
)
def test_training_a_running_average_is_refused(overrides, train_cfg):
    from src.prepare import prepare_training

    with pytest.raises(ConfigError) as err:
        prepare_training(train_cfg(*overrides), [], {})
    refused(str(err.value), overrides[0].split("=")[1], "python -m src.eval")


# ------------------------------------------------------------ a refusal in the run's train.log
def test_a_model_that_cannot_be_built_says_why_in_its_run_folders_train_log(
    tmp_path, synthetic_data_dir
):
    """A sweep job's folder stays when the job is refused (as does a run's that had begun);
    its train.log used to end without the error. The network is built only once the data is
    loaded (it needs the pose size), so this refusal comes in the job, not before the sweep."""
    proc = run_module(
        "src.train",
        "hydra.mode=MULTIRUN",
        "model=residual_mlp",
        "model.net.hidden=0",
        "data=synthetic",
        "iterations=2",
        "val_every=2",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    message = _error_line(proc).removeprefix("error: ")
    assert "hidden=0" in message and "must be >= 1" in message, message  # value and fix
    (log,) = tmp_path.glob("train/multiruns/*/0_*/train.log")
    assert message in log.read_text()
    # On the console once: printed by the refusal, not logged there again.
    assert (proc.stdout + proc.stderr).count(message) == 1


# ------------------------------------------------------------ row 7: published numbers, titles
def test_published_numbers_only_beside_results_on_their_dataset():
    from src.reporting.published import published_for

    ref = {"paper": "martinez2017", "method": "zero_velocity"}
    assert published_for(ref, "synthetic") == (None, None)
    assert published_for(ref, "cmu") == (None, None)  # Martinez published no CMU numbers
    table, label = published_for(ref, "h36m")
    assert label == "martinez2017 zero_velocity" and table["walking"][80] == 0.39
    per_dataset = {"h36m": ref, "cmu": {"paper": "li2018", "method": "rrnn"}}
    assert published_for(per_dataset, "cmu")[1] == "li2018 rrnn"
    assert published_for(per_dataset, "synthetic") == (None, None)


@pytest.fixture(scope="module")
def synthetic_zero_velocity(tmp_path_factory, synthetic_data_dir):
    from src.results import build_for_evaluation

    cfg = compose_config(
        "visualize",
        ["model=zero_velocity", "data=synthetic", "trainer=cpu"],
        tmp_path_factory.mktemp("eval"),
        synthetic_data_dir,
    )
    dm, module = build_for_evaluation(cfg)
    model_cfg = module.run_info["config"]["model"]
    dataset = module.run_info["config"]["data"]["name"]
    L.Trainer(accelerator="cpu", logger=False, enable_progress_bar=False).test(
        module, datamodule=dm, verbose=False
    )
    return dm, module, model_cfg, dataset


def test_eval_tables_of_synthetic_data_carry_no_published_numbers(synthetic_zero_velocity):
    from src.results import build_tables, table_markdown

    dm, module, model_cfg, dataset = synthetic_zero_velocity
    assert dataset == "synthetic" and dm.dataset_name == "h36m"  # H3.6M format, not H3.6M
    euler, mpjpe = build_tables(module, dm, model_cfg, dataset)
    assert euler["published"] is None and euler["published_label"] is None
    assert "on synthetic" in euler["title"] and "h36m" not in euler["title"]
    assert "published" not in table_markdown(euler).lower()


def test_visualize_title_names_the_real_dataset(synthetic_zero_velocity):
    from src.plots import window_rows

    dm, module, _, _ = synthetic_zero_velocity
    _, _, what = window_rows(dm, module, 0, observed_shown=5)
    assert " on synthetic: walking, window 0" in what
    assert "h36m" not in what


# ------------------------------------------------------------ row 9: misspelt keys
def test_cli_misspelt_key_names_the_close_matches(tmp_path, synthetic_data_dir):
    entries = ["src.train", "src.eval", "src.visualize"]
    procs = run_in_one_process(
        *([e, "data=synthetic", *([] if e == "src.train" else ["model=zero_velocity"]),
           "trainer.max_step=3"] for e in entries),
        data_dir=synthetic_data_dir, log_dir=tmp_path,
    )  # fmt: skip
    for proc in procs:
        refused(_error_line(proc), "trainer.max_step", "+trainer.max_steps")
    assert not list(tmp_path.rglob("checkpoints"))


def test_misspelt_key_in_train_config_names_the_close_matches(monkeypatch, capsys):
    """The same on the train config, in-process, through the entry points' decorator."""
    from src.cli import hydra_entry

    called = []
    entry = hydra_entry("train")(lambda cfg: called.append(cfg))
    for argv, expected in [
        (["trainr.max_steps=3"], ["trainr.max_steps", "trainer.max_steps?"]),
        (["model.net.kernl=[3,3]"], ["model.net.kernl", "model.net.kernel?"]),
        (["dta=cmu"], ["dta", "data?"]),
        (["data=h36n"], ["data=h36n", "data=h36m?", "cmu, h36m, synthetic"]),
    ]:
        monkeypatch.setattr(sys, "argv", ["src.train", *argv])
        with pytest.raises(SystemExit) as info:
            entry()
        assert info.value.code == 2
        err = capsys.readouterr().err
        refused(err, *expected)
        assert err.startswith("error: ") and err.count("\n") == 1, err
    assert not called


@pytest.mark.parametrize("entry", ["eval", "visualize"])
def test_key_of_a_group_left_unchosen_says_to_choose_it(entry, monkeypatch, capsys):
    """src.eval ckpt_path=... data.batch_size=8: the data comes from the checkpoint, so no data
    option is chosen; the message used to be "no such key. Did you mean data.batch_size?"."""
    from src.cli import hydra_entry

    called = []
    main = hydra_entry(entry)(lambda cfg: called.append(cfg))
    monkeypatch.setattr(sys, "argv", [entry, "ckpt_path=a.ckpt", "data.batch_size=8"])
    with pytest.raises(SystemExit) as info:
        main()
    assert info.value.code == 2 and not called
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    refused(err, "data.batch_size", "data=cmu|h36m|synthetic")


@pytest.mark.parametrize("entry", ["eval", "visualize"])
def test_allow_partial_beside_a_checkpoint_is_taken(entry, tmp_path, monkeypatch):
    """src.eval ckpt_path=... data.allow_partial=true used to be refused, asking for a data=
    option that the checkpoint fixes. Whether this machine's copy lacks files is a fact of the
    machine (paths.allow_partial, which the checkpoint's data config takes:
    results.build_for_evaluation): the override sets it."""
    from src.cli import hydra_entry

    called = []
    main = hydra_entry(entry)(lambda cfg: called.append(cfg))
    argv = [entry, "ckpt_path=a.ckpt", "data.allow_partial=true", f"paths.log_dir={tmp_path}"]
    monkeypatch.setattr(sys, "argv", argv)
    main()
    (cfg,) = called
    assert cfg.paths.allow_partial is True and cfg.get("data") is None


def test_allow_partial_is_named_alike_everywhere_and_taken_as_named(
    help_text, tmp_path, monkeypatch
):
    """`src.train --help` named paths.allow_partial=true, the docs and the data's own warning
    data.allow_partial=true. One key is named in every --help, the README and docs and the
    refusal of a partial copy; given on each entry point's command line, the data takes it."""
    from src.cli import hydra_entry
    from src.data.h36m import H36MDataModule
    from src.data.synthetic import SyntheticDataModule
    from tests.conftest import ROOT

    SyntheticDataModule(tmp_path / "copy").prepare_data()
    (tmp_path / "copy" / "synthetic" / "h3.6m/dataset/S5/eating_2.txt").unlink()
    with pytest.raises(DataError) as refusal:
        H36MDataModule(tmp_path / "copy" / "synthetic", train_subjects=(1,)).prepare_data()
    texts = [str(refusal.value), (ROOT / "README.md").read_text()]
    texts += [p.read_text() for p in sorted((ROOT / "docs").glob("*.md"))]
    texts += [help_text(f"src.{e}") for e in ("train", "eval", "visualize", "export_windows")]
    named = {key for text in texts for key in re.findall(r"([\w.]*allow_partial)=", text)}
    assert len(named) == 1, named
    (key,) = named

    monkeypatch.delenv("MOTION_ALLOW_PARTIAL", raising=False)
    for entry, chosen in [
        ("train", ["data=synthetic"]),
        ("eval", ["model=zero_velocity", "data=synthetic"]),
        ("eval", ["ckpt_path=a.ckpt"]),  # the checkpoint's data config takes paths.*
        ("visualize", ["ckpt_path=a.ckpt"]),
        ("export_windows", ["data=synthetic"]),
    ]:
        called = []
        main = hydra_entry(entry)(lambda cfg, called=called: called.append(cfg))
        argv = [entry, *chosen, f"{key}=true", f"paths.log_dir={tmp_path / 'out'}"]
        monkeypatch.setattr(sys, "argv", argv)
        main()
        (cfg,) = called
        taken = cfg.data.allow_partial if cfg.get("data") else cfg.paths.allow_partial
        assert taken is True, (entry, chosen)


@pytest.mark.parametrize(("value", "expected"), [(None, False), ("true", True), ("false", False)])
def test_allow_partial_defaults_from_the_environment(value, expected, tmp_path, monkeypatch):
    """The README's quick start exports MOTION_ALLOW_PARTIAL=true once, beside MOTION_ARCHIVES,
    and every command runs as written on a copy that lacks files; unset, a partial copy is
    refused listing the missing files (tests/test_data_real.py)."""
    if value is None:
        monkeypatch.delenv("MOTION_ALLOW_PARTIAL", raising=False)
    else:
        monkeypatch.setenv("MOTION_ALLOW_PARTIAL", value)
    compositions = [("train", ["data=cmu"]), ("eval", ["model=zero_velocity", "data=h36m"])]
    for name, overrides in compositions:
        cfg = compose_config(name, overrides, tmp_path)
        assert cfg.data.allow_partial is expected and cfg.paths.allow_partial is expected
    monkeypatch.setenv("MOTION_ALLOW_PARTIAL", "maybe")
    from src.config import check

    with pytest.raises(ConfigError) as err:
        check(compose_config("train", [], tmp_path), "train")
    refused(str(err.value), "paths.allow_partial='maybe'", "true or false")


def test_cli_added_key_that_no_constructor_takes_is_one_line(tmp_path, synthetic_data_dir):
    proc = run_module(
        "src.train",
        "data=synthetic",
        "+trainer.max_step=3",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    refused(_error_line(proc), "trainer.max_step", "lightning.pytorch.trainer.Trainer", "max_steps")


@pytest.mark.parametrize(
    ("override", "named"),
    [
        ("+model.net.kernal=[3,3]", ["model.net.kernal", "ConvSeq2Seq", "model.net.kernel?"]),
        ("+sampling.ete=0.5", ["sampling.ete", "eta_schedule.Constant", "sampling.eta?"]),
    ],
)
def test_added_keys_are_checked_against_their_constructor(override, named, train_cfg):
    from src.prepare import prepare_training

    with pytest.raises(ConfigError) as err:
        prepare_training(train_cfg(override), [], {})
    refused(str(err.value), *named)


@pytest.mark.parametrize("experiment", sorted(p.stem for p in (CONF / "experiment").glob("*.yaml")))
def test_every_shipped_config_passes_the_constructor_check(experiment, train_cfg):
    from src.config import check

    check(train_cfg(f"experiment={experiment}"), "train")


# ------------------------------------------------------------ row 10: --help
def _options(group: str) -> set[str]:
    return {p.stem for p in (CONF / group).glob("*.yaml")}


def test_train_help_lists_its_groups(help_text):
    text = help_text("src.train")
    for group in ("data", "model", "sampling", "adversarial", "trainer", "experiment", "debug"):
        line = next(x for x in text.splitlines() if x.startswith(f"{group}: "))
        assert set(line.split(": ", 1)[1].split(", ")) == _options(group)


@pytest.mark.parametrize("entry", ["src.eval", "src.visualize"])
def test_eval_and_visualize_help_list_only_what_they_accept(entry, help_text):
    text = help_text(entry)
    groups = text.split("== Config groups (group=option) ==")[1].split("==")[0]
    listed = dict(re.findall(r"^(\w+): ([\w, ]+?)\s{2,}", groups, flags=re.M))
    assert set(listed) == {"data", "model", "trainer"}
    assert set(listed["data"].split(", ")) == _options("data")
    models = set(listed["model"].split(", "))
    assert models <= _options("model")
    for model in models:  # only baselines: a trained model comes with ckpt_path=
        net = OmegaConf.load(CONF / "model" / f"{model}.yaml").net._target_
        assert hydra.utils.get_class(net).trainable is False
    assert set(listed["trainer"].split(", ")) <= _options("trainer")
    for group in ("experiment", "debug", "hparams_search"):
        assert group not in text
    assert "ckpt_path=" in text


def test_plot_errors_help_lists_its_arguments(help_text):
    text = help_text("src.plot_errors")
    for key in ("results=", "metric=", "action=", "labels=", "published=", "out="):
        assert f"\n  {key}" in text


def test_report_help_lists_its_arguments(help_text):
    text = help_text("src.report")
    for key in ("runs=", "records=", "out=", "readme=", "budget=", "datasets=", "protocols="):
        assert f"\n{key}" in text


def test_plot_errors_unknown_argument_names_the_close_one(tmp_path):
    proc = run_module(
        "src.plot_errors", "results=[a.json]", "metrc=mpjpe", data_dir=tmp_path, log_dir=tmp_path
    )
    refused(_error_line(proc), "metrc", "metric?")
    assert proc.stderr.count("\n") == 1


# ------------------------------------------------------------ row 12: legends, mixed datasets
def _results(path: Path, model: str, dataset: str, **provenance) -> Path:
    table = {
        "metric": "euler",
        "unit": "rad",
        "actions": ["walking"],
        "values": {"walking": {"80": 0.3, "160": 0.5}},
        "absent": {},
        "average": {"values": {"80": 0.3, "160": 0.5}},
        "published": {"average": {"80": 0.2, "160": 0.4}},
        "published_label": "martinez2017 zero_velocity",
    }
    prov = {"model": model, "dataset": dataset, **provenance}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"provenance": prov, "tables": [table]}))
    return path


def test_plot_errors_refuses_results_of_different_datasets(tmp_path):
    cmu = _results(tmp_path / "cmu" / "results.json", "zero_velocity", "cmu")
    h36m = _results(tmp_path / "h36m" / "results.json", "zero_velocity", "h36m")
    proc = run_module(
        "src.plot_errors",
        f"results=[{cmu},{h36m}]",
        f"out={tmp_path / 'e.png'}",
        data_dir=tmp_path,
        log_dir=tmp_path,
    )
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: the results come from different datasets (cmu, h36m)")
    assert proc.stderr.count("\n") == 1 and not (tmp_path / "e.png").exists()
    assert not (tmp_path / "plot_errors").exists()  # a refused plot leaves no folder behind


def test_plot_errors_legend_tells_runs_apart(tmp_path):
    from src.plot_errors import legend_labels

    a = _results(tmp_path / "a" / "results.json", "conv_s2s", "cmu", run_name="li2018_cmu")
    b = _results(tmp_path / "b" / "results.json", "conv_s2s", "cmu", run_name="li2018_cmu")
    c = _results(tmp_path / "c" / "results.json", "zero_velocity", "cmu")
    d = _results(tmp_path / "d" / "results.json", "zero_velocity", "cmu", eval_protocol="random")
    e = _results(tmp_path / "e" / "results.json", "zero_velocity", "cmu", eval_protocol="srnn")
    paths = [a, b, c, d, e]
    labels = legend_labels([json.loads(p.read_text()) for p in paths], paths)
    assert labels[:3] == ["li2018_cmu (cmu), a", "li2018_cmu (cmu), b", "zero_velocity (cmu)"]
    assert labels[3:] == ["zero_velocity (cmu), random", "zero_velocity (cmu), srnn"]
    assert len(set(labels)) == len(labels)


def test_plot_errors_draws_distinct_legend_entries(tmp_path):
    from src.plot_errors import plot_errors

    runs = [_results(tmp_path / f"{i}" / "results.json", "zero_velocity", "h36m") for i in "ab"]
    out = plot_errors(runs, tmp_path / "e.png", published=True)
    assert out.is_file()
    with pytest.raises(ConfigError, match="more than once"):
        plot_errors(runs, tmp_path / "f.png", labels=["x", "x"])


def test_plot_errors_never_writes_over_a_file(tmp_path):
    """A second plot to the same out= used to replace the first silently, and so did every
    plot with the default out (outputs/plots/errors_<metric>_<action>.png); out=<a folder>
    wrote <folder>.png while printing the folder, and out=e.xyz ended in a traceback."""
    import src.plot_errors as plot_errors_module

    run = _results(tmp_path / "a" / "results.json", "zero_velocity", "h36m")
    out = plot_errors_module.plot_errors([run], tmp_path / "e.png")
    first = out.read_bytes()
    for target, message in [
        (out, "already exists; nothing was overwritten"),
        (tmp_path / "a", "has no image extension"),
        (tmp_path / "e.xyz", "has no image extension"),
    ]:
        with pytest.raises(ConfigError, match=message):
            plot_errors_module.plot_errors([run], target, action="walking")
    assert out.read_bytes() == first and not (tmp_path / "a.png").exists()
    # Without out= each plot goes into its own new run folder, as every entry point's output.
    twice = [["src.plot_errors", f"results=[{run}]"]] * 2
    for proc in run_in_one_process(*twice, data_dir=tmp_path, log_dir=tmp_path / "logs"):
        assert proc.returncode == 0, proc.stderr[-2000:]
    written = sorted((tmp_path / "logs" / "plot_errors").rglob("errors_euler_average.png"))
    assert len(written) == 2 and written[0].parent != written[1].parent


def test_plot_errors_shows_no_published_curve_for_synthetic_results(tmp_path, monkeypatch):
    import src.plot_errors as plot_errors_module

    drawn, draw = {}, plot_errors_module.error_vs_horizon

    def capture(curves, **kwargs):
        drawn["labels"] = [label for label, _ in curves]
        return draw(curves, **kwargs)

    monkeypatch.setattr(plot_errors_module, "error_vs_horizon", capture)
    runs = [_results(tmp_path / "s" / "results.json", "zero_velocity", "synthetic")]
    plot_errors_module.plot_errors(runs, tmp_path / "e.png", published=True)
    assert drawn["labels"] == ["zero_velocity (synthetic)"]


# ------------------------------------------------------------ row 13: non-editable install
def test_installed_without_the_configs_is_one_line(tmp_path, monkeypatch, capsys):
    """`pip install .` leaves the configs behind: simulated by pointing the config folder at
    a place that does not exist, as it is beside an installed copy in site-packages."""
    import src.cli as cli
    from src.eval import main

    monkeypatch.setattr(cli, "CONF_DIR", tmp_path / "site-packages" / "conf")
    monkeypatch.setattr(sys, "argv", ["src.eval", "model=zero_velocity", "data=synthetic"])
    with pytest.raises(SystemExit) as info:
        main()
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install -e ." in err
    assert str(tmp_path / "site-packages" / "conf") in err
