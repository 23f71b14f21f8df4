"""Every config composes and instantiates; typos get Hydra's clear errors."""

import re
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Literal, Optional

import hydra
import pytest
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

from tests.conftest import CONF, compose_config, refused, run_module

EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_composes_and_instantiates(experiment, tmp_path, synthetic_data_dir):
    from src.build import build_module

    cfg = compose_config(
        "train", [f"experiment={experiment}"], tmp_path / "run", synthetic_data_dir
    )
    # Every interpolation resolves.
    OmegaConf.to_container(
        OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]), resolve=True
    )
    # Instantiate on the synthetic data so the check is about the configs, not the archives.
    synth = compose_config("train", ["data=synthetic"], tmp_path / "s", synthetic_data_dir)
    from src.build import build_datamodule

    data_cfg = OmegaConf.merge(synth.data, {"actions": synth.data.actions})
    dm = build_datamodule(data_cfg)
    dm.prepare_data()
    dm.setup("fit")
    module = build_module(cfg, dm)
    assert module.trainable
    assert module.adversarial == bool(cfg.adversarial.get("enabled"))
    hydra.utils.instantiate(cfg.sampling)(0)


def test_model_groups_switch_defaults(tmp_path, synthetic_data_dir):
    conv = compose_config("train", ["model=conv_s2s"], tmp_path / "a", synthetic_data_dir)
    assert conv.adversarial.enabled and conv.sampling.eta == 0.95
    gru = compose_config("train", ["model=gru_s2s"], tmp_path / "b", synthetic_data_dir)
    assert not gru.adversarial.enabled and gru.sampling.eta == 1.0
    # The command line still wins over the model's choice.
    gru_adv = compose_config(
        "train", ["model=gru_s2s", "adversarial=li2018"], tmp_path / "c", synthetic_data_dir
    )
    assert gru_adv.adversarial.enabled


def test_misspelt_group_option_names_the_choices(tmp_path):
    with pytest.raises(ConfigCompositionException, match=r"(?s)data/h36n.*cmu.*h36m"):
        compose_config("train", ["data=h36n"], tmp_path)


def test_misspelt_key_is_rejected(tmp_path):
    with pytest.raises(ConfigCompositionException, match="batchsize"):
        compose_config("train", ["data.batchsize=8"], tmp_path)


@pytest.mark.parametrize(
    ("override", "named"),
    [
        ("sampling.eta=1.5", ["sampling.eta=1.5", "[0, 1]"]),
        ("model.optimizer.lr=-0.1", ["model.optimizer", "learning rate: -0.1"]),  # torch's
        ("model.optimizer.lr=0", ["model.optimizer.lr=0", "> 0"]),  # torch takes it
        ("model.net.C=60", ["model.net.C=60", "observed_len=50"]),  # ConvSeq2Seq's own check
        ("iterations=0", ["iterations=0", ">= 1"]),
        ("sampling=linear", ["sampling.steps=0", "positive"]),  # with sampling.steps=0
    ],
)
def test_out_of_range_values_are_rejected_before_training(
    override, named, tmp_path, synthetic_data_dir
):
    from src.config import ConfigError
    from src.prepare import prepare_training

    extra = ["sampling.steps=0"] if override == "sampling=linear" else []
    cfg = compose_config(
        "train", ["data=synthetic", override, *extra], tmp_path, synthetic_data_dir
    )
    with pytest.raises(ConfigError) as err:
        prepare_training(cfg, [], {})
    refused(str(err.value), *named)


def test_cli_reports_config_error_in_one_line(tmp_path, synthetic_data_dir):
    proc = run_module(
        "src.train",
        "data=synthetic",
        "sampling.eta=2",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 2
    (line,) = [x for x in proc.stderr.splitlines() if x.startswith("error: ")]
    refused(line, "sampling.eta=2", "[0, 1]")
    assert "Traceback" not in proc.stderr


def test_unwritable_output_folder_fails_before_training(tmp_path, synthetic_data_dir):
    # A file where a folder should be stops even root, so the test holds for every user.
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("")
    proc = run_module(
        "src.train", "data=synthetic", data_dir=synthetic_data_dir, log_dir=blocker / "sub"
    )
    assert proc.returncode == 2
    assert "cannot write the run folder" in proc.stderr and "Not a directory" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (blocker.parent / "checkpoints").exists()


def test_runs_never_share_a_folder(tmp_path):
    cfg = compose_config("train", [], tmp_path)
    run_dir = cfg.hydra.run.dir
    assert "${now:" in OmegaConf.to_container(cfg.hydra, resolve=False)["run"]["dir"]
    assert Path(str(run_dir)).name  # timestamped leaf


@pytest.mark.parametrize(
    ("override", "named"),
    [
        ("metrics.dim_rule=futur", ["metrics.dim_rule='futur'", "future, window"]),
        ("protocol=srn", ["protocol='srn'", "srnn, random, strided"]),
    ],
)
def test_eval_settings_are_validated(override, named, tmp_path):
    from src.config import ConfigError, check

    cfg = compose_config("eval", ["model=zero_velocity", "data=h36m", override], tmp_path)
    with pytest.raises(ConfigError) as err:
        check(cfg, "eval")
    refused(str(err.value), *named)


WHOLE, NUMBER = "Integer|whole number", "Float|a number"


@pytest.mark.parametrize(
    ("override", "kind"),
    [
        ("iterations=abc", WHOLE),
        ("iterations=1.5", WHOLE),
        ("val_every=abc", WHOLE),
        ("seed=abc", WHOLE),
        ("seed=-3", r"\[0, 4294967295\]"),
        ("seed=4294967296", r"\[0, 4294967295\]"),
        ("data.batch_size=abc", WHOLE),
        ("checkpoint_every=abc", WHOLE),
        ("checkpoint_every=-1", ">= 0"),
        ("progress_every_s=abc", NUMBER),
        ("model.optimizer.lr=abc", NUMBER),
        ("sampling.eta=abc", NUMBER),
        ("model.lr_decay_gamma=abc", NUMBER),
        ("compile.enabled=maybe", "true, false or auto"),
    ],
)
def test_values_of_the_wrong_type_are_rejected_before_training(
    override, kind, tmp_path, synthetic_data_dir
):
    """A word where a number belongs used to fail inside a comparison, with a traceback
    (iterations=abc), or be truncated (iterations=1.5 ran as 1). Hydra refuses a top-level
    key's type while composing (src/config.py's schema), the checks the rest."""
    from src.cli import hydra_error
    from src.config import ConfigError
    from src.prepare import prepare_training

    key, value = override.split("=")
    try:
        cfg = compose_config("train", ["data=synthetic", override], tmp_path, synthetic_data_dir)
        with pytest.raises(ConfigError) as err:
            prepare_training(cfg, [], {})
        message = str(err.value)
    except ConfigCompositionException as hydra_err:
        message = hydra_error(hydra_err, "train")
    refused(message, key, value)
    assert re.search(kind, message), message


def test_cli_value_of_the_wrong_type_is_one_line(tmp_path, synthetic_data_dir):
    proc = run_module(
        "src.train",
        "data=synthetic",
        "iterations=abc",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    (line,) = [x for x in proc.stderr.splitlines() if x.startswith("error: ")]
    refused(line, "iterations=abc", "Integer")
    assert "Traceback" not in proc.stderr and not list(tmp_path.rglob("*"))


class EveryAnnotation:
    """A constructor with every annotation a new model may carry (docs/extending.md)."""

    def __init__(  # noqa: PLR0913
        self,
        a: tuple = (2, 7),
        b: typing.Tuple = (1,),  # noqa: UP006
        c: list = (1,),
        d: typing.List = (1,),  # noqa: UP006
        e: Sequence[int] = (1,),
        f: typing.Sequence = (1,),  # noqa: UP006
        g: tuple[int, int] = (2, 7),
        h: typing.Tuple[float, ...] = (0.5,),  # noqa: UP006
        i: int | None = None,
        j: Optional[float] = None,  # noqa: UP045
        k: Literal["x", "y"] = "x",
        m: list[float] = (1.0,),
    ):
        pass


@pytest.mark.parametrize(
    ("values", "refusal"),
    [
        ({"a": [2, 7], "b": [1, 2, 3], "c": [1], "d": [1, "x"], "e": [1, 2], "f": ["x"],
          "g": [3, 3], "h": [0.1, 2], "i": None, "j": 1, "k": "y", "m": [1, 2.5]}, None),
        ({"i": 3}, None),
        ({"g": [2, "x"]}, ["model.net.g[1]='x'", "a whole number"]),
        ({"g": [2]}, ["model.net.g=[2]", "a list of 2 values"]),
        ({"m": ["x"]}, ["model.net.m[0]='x'", "a number"]),
        ({"i": "no"}, ["model.net.i='no'", "a whole number or null"]),
        ({"j": "x"}, ["model.net.j='x'", "a number or null"]),
        ({"a": 2}, ["model.net.a=2", "a list"]),
        ({"e": "no"}, ["model.net.e='no'", "true or false"]),  # untyped: a boolean word
        ({"kernel": [2, 7]}, ["model.net.kernel", f"argument of {__name__}.EveryAnnotation"]),
    ],
)  # fmt: skip
def test_every_annotation_a_constructor_can_carry_is_read(values, refusal, tmp_path):
    """`conforms([2, 7], tuple)` used to be False (a model with `kernel: tuple = (2, 7)` was
    refused) and typing.List or Sequence raised IndexError. Each annotation is read by
    hydra-zen and checked by OmegaConf where it has a type OmegaConf holds (a Literal, a
    Sequence and a union are the constructor's to check)."""
    from omegaconf import open_dict

    from src.config import ConfigError, check_types

    cfg = compose_config("train", [], tmp_path)
    with open_dict(cfg):
        cfg.model.net = {"_target_": f"{__name__}.EveryAnnotation", **values}
    if refusal is None:
        check_types(cfg, "train")
    else:
        with pytest.raises(ConfigError) as err:
            check_types(cfg, "train")
        refused(str(err.value), *refusal)
