"""What the user typed is what runs (issue #26): a misspelt option of any config group and a
value of the wrong type are refused before anything runs, never replaced by a default; and the
rows of the issue's table, one section each."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from src.lit.factory import ConfigError
from tests.conftest import CONF


def _groups() -> list[str]:
    """Every config group under conf/ (hydra/launcher included), read from the folders."""
    return sorted(
        str(folder.relative_to(CONF))
        for folder in CONF.rglob("*")
        if folder.is_dir() and list(folder.glob("*.yaml"))
    )


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


def _refusal(config_name: str, argv: list[str], monkeypatch, capsys) -> str:
    """The one error line of `python -m src.<config_name> argv...`, in-process, through the
    entry points' decorator; the task must not run."""
    from src.cli import hydra_entry

    called = []
    monkeypatch.setattr(sys, "argv", [f"src.{config_name}", *argv])
    with pytest.raises(SystemExit) as info:
        hydra_entry(config_name)(lambda cfg: called.append(cfg))()
    assert info.value.code == 2 and not called
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: "), err
    return err.strip()


# ------------------------------------------------ rows 1-2: a misspelt option of any group
def _misspelt(options: list[str]) -> str:
    """An option one letter off the first one, which is no option itself."""
    wrong = options[0][:-1]
    return wrong if wrong and wrong not in options else options[0] + "x"


GROUPS_OF = {
    "train": _groups(),
    # eval and visualize compose the groups of their defaults lists (and Hydra's own).
    "eval": [g for g in _groups() if g.split("/")[0] in
             ("paths", "data", "sampling", "adversarial", "model", "trainer", "hydra")],
}  # fmt: skip
GROUPS_OF["visualize"] = GROUPS_OF["eval"]


@pytest.mark.parametrize(
    ("config_name", "group"),
    [(config, group) for config, groups in GROUPS_OF.items() for group in groups],
)
def test_a_misspelt_option_of_every_group_is_refused_naming_the_options(
    config_name, group, tmp_path, monkeypatch, capsys
):
    """Before, the `optional` groups of conf/train.yaml (experiment, reproduce, debug,
    hparams_search) ignored an option that does not exist: `debug=fast` trained 20,000
    iterations of the defaults."""
    options = _options(group)
    wrong = _misspelt(options)
    err = _refusal(config_name, [f"{group}={wrong}", f"paths.log_dir={tmp_path}"], monkeypatch,
                   capsys)  # fmt: skip
    assert err.startswith(f"error: {group}={wrong}: no such option of {config_name}."), err
    listed = err.split("Choose one of: ")[1].rstrip(".").split(", ")
    assert set(options) <= set(listed), err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        # row 1: one word off; it used to train the default conv_s2s on H3.6M
        (["experiment=martinez2017_residual_sup"],
         "error: experiment=martinez2017_residual_sup: no such option of train. Did you mean "
         "experiment=martinez2017_res_sup"),
        # row 2: a 20,000-iteration run (ETA 7 h) instead of a debug run; one default run
        # instead of a sweep
        (["debug=fast", "data=synthetic"],
         "error: debug=fast: no such option of train. Did you mean debug=fast_dev_run?"),
        (["-m", "reproduce=paper"],
         "error: reproduce=paper: no such option of train. Did you mean reproduce=papers"),
        (["-m", "hparams_search=optuna"],
         "error: hparams_search=optuna: no such option of train. Did you mean "
         "hparams_search=conv_s2s_optuna? Choose one of: conv_s2s_optuna."),
    ],
)  # fmt: skip
def test_rows_1_2_misspelt_experiment_debug_and_sweeps_are_refused(
    argv, expected, tmp_path, monkeypatch, capsys
):
    err = _refusal("train", [*argv, f"paths.log_dir={tmp_path}"], monkeypatch, capsys)
    assert err.startswith(expected), err
    assert not list(tmp_path.iterdir())  # no run folder, no sweep folder


def test_optional_groups_left_unset_still_compose(tmp_path):
    from tests.conftest import compose_config

    cfg = compose_config("train", [], tmp_path)
    choices = cfg.hydra.runtime.choices
    assert [choices[g] for g in ("experiment", "reproduce", "debug", "hparams_search")] == [
        None
    ] * 4
    assert cfg.model.name == "conv_s2s" and cfg.iterations == 20000
