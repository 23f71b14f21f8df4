"""What the user typed is what runs (issue #26): a misspelt option of any config group and a
value of the wrong type are refused before anything runs, never replaced by a default; and the
rows of the issue's table, one section each."""

from __future__ import annotations

import sys

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


# ------------------------------------------- rows 3-4: values checked against their types
def _leaves(node: dict, path: str = ""):
    for key, value in node.items():
        here = f"{path}.{key}" if path else str(key)
        if isinstance(value, dict):
            yield from _leaves(value, here)
        else:
            yield here, value


# The default config, and each option that brings boolean keys of its own.
BOOLEAN_CONFIGS = [
    ("train", []),
    ("train", ["model=gru_s2s"]),
    ("train", ["trainer=ddp"]),
    ("eval", ["model=zero_velocity", "data=h36m"]),
    ("visualize", ["model=zero_velocity", "data=h36m"]),
]


def _boolean_keys() -> list[tuple[str, list[str], str]]:
    from omegaconf import OmegaConf

    from tests.conftest import compose_config

    found = {}
    for config_name, base in BOOLEAN_CONFIGS:
        cfg = compose_config(config_name, base, "/nonexistent")
        plain = OmegaConf.to_container(cfg, resolve=False)
        del plain["hydra"]  # Hydra's own config (--cfg job leaves it out too)
        for key, value in _leaves(plain):
            if isinstance(value, bool):
                found.setdefault((config_name, key), base)
    return [(config_name, base, key) for (config_name, key), base in found.items()]


BOOLEAN_KEYS = _boolean_keys()


def test_the_boolean_keys_cover_what_the_issue_names():
    keys = {key for _, _, key in BOOLEAN_KEYS}
    assert {"model.net.long_term", "data.allow_partial", "adversarial.enabled",
            "trainer.deterministic", "model.net.tied", "baseline"} <= keys  # fmt: skip
    assert len(keys) >= 15


@pytest.mark.parametrize(("config_name", "base", "key"), BOOLEAN_KEYS)
def test_every_boolean_key_set_to_no_is_refused_or_false_never_true(
    config_name, base, key, tmp_path
):
    """Hydra reads `key=no` as the string 'no', which Python takes as true: the long-term
    encoder stayed (row 3), data.allow_partial=no trained on a partial copy (row 4)."""
    from omegaconf import OmegaConf

    from src.lit.schema import SCHEMAS
    from src.lit.validation import validate_eval_config, validate_train_config
    from tests.conftest import compose_config

    cfg = compose_config(config_name, [*base, f"{key}=no"], tmp_path)
    try:
        if config_name == "train":
            validate_train_config(cfg)
        else:
            validate_eval_config(cfg, SCHEMAS[config_name])
    except ConfigError as err:
        assert str(err).startswith(f"{key}='no' must be true") and "false" in str(err), err
        return
    assert OmegaConf.select(cfg, key) is False


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        # row 3: the ablation ran the full model (5.8 M parameters, as with true)
        (["model.net.long_term=no"], "model.net.long_term='no' must be true or false."),
        # row 4: logged allow_partial=true and trained
        (["data=cmu", "data.allow_partial=no"], "data.allow_partial='no' must be true or false."),
        (["data.allow_partial=yes"], "data.allow_partial='yes' must be true or false."),
        (["trainer.deterministic=off"], "trainer.deterministic='off' must be true, false, warn "
                                        "or null."),
        (["+trainer.precision=bf17"], "trainer.precision='bf17' must be 64, 32, 16, "),
        (["model.net.kernel=[2]"], "model.net.kernel=[2] must be a list of 2 whole numbers."),
        (["model.net.dropout=0.5"], "model.net.dropout=0.5 must be a list of 3 numbers."),
        (["model.lr_decay_every=1e4"], "model.lr_decay_every=10000.0 must be a whole number."),
        (["adversarial.enabled=1"], "adversarial.enabled=1 must be true or false."),
        (["sampling=linear", "sampling.steps=abc"], "sampling.steps='abc' must be a whole "
                                                    "number."),
        (["+model.net.d_dec=1.5"], "model.net.d_dec=1.5 must be a whole number."),
        (["model.optimizer._partial_=no"], "model.optimizer._partial_='no' must be true or "
                                           "false."),
        # a key added with + that nothing reads (Hydra adds it without a word)
        (["+iteratons=100"], "iteratons: no such setting at the top level, so nothing would "
                             "read it (a + adds only what the code takes). Did you mean "
                             "iterations?"),
        (["+model.lr_decay=3"], "model.lr_decay: no such setting under model"),
    ],
)  # fmt: skip
def test_rows_3_4_values_of_the_wrong_type_are_refused_naming_the_type(
    overrides, message, train_cfg
):
    from src.lit.validation import validate_train_config

    with pytest.raises(ConfigError) as err:
        validate_train_config(train_cfg(*overrides))
    assert str(err.value).startswith(message), str(err.value)


def test_row_3_long_term_false_builds_the_ablation(train_cfg, synthetic_data_dir):
    from src.lit.factory import build_datamodule, build_module
    from src.lit.validation import validate_train_config

    sizes = {}
    for value in ("true", "false"):
        cfg = train_cfg(f"model.net.long_term={value}", "adversarial=none")
        validate_train_config(cfg)
        dm = build_datamodule(cfg.data)
        dm.prepare_data()
        dm.setup("fit")
        sizes[value] = sum(p.numel() for p in build_module(cfg, dm).net.parameters())
    assert sizes["false"] < sizes["true"] / 2  # 2.0 M against 5.8 M on H3.6M


def test_every_key_of_every_shipped_config_has_a_declared_type(tmp_path):
    """One declaration per key (src/lit/schema.py, or the constructor a node instantiates): a
    key added to a config without a type is caught here, not by a user."""
    from src.lit.schema import SCHEMAS, check_types
    from src.lit.validation import check_constructor_keys
    from tests.conftest import compose_config

    compositions = [("train", [f"{group}={option}"]) for group in _groups()
                    if not group.startswith("hydra") for option in _options(group)]  # fmt: skip
    compositions += [(name, ["model=zero_velocity", "data=cmu"]) for name in ("eval", "visualize")]
    compositions += [(name, ["ckpt_path=a.ckpt"]) for name in ("eval", "visualize")]
    for config_name, overrides in compositions:
        cfg = compose_config(config_name, overrides, tmp_path)
        check_constructor_keys(cfg)
        check_types(cfg, SCHEMAS[config_name])
