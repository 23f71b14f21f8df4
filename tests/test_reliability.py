"""The project's reliability guarantees (docs/guarantees.md), one test each: determinism,
guarded numerics, checkpoint/config mismatches, nothing lost, config errors. Kill-and-resume
is in test_resume.py, corrupted data files in test_corrupt_data.py."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from src.build import check_normalizer
from src.cli import hydra_entry
from src.config import ConfigError
from src.data.errors import DataError
from src.data.normalization import Normalizer
from src.lit.checkpoints import CheckpointError, read_checkpoint
from src.lit.predictor import MotionPredictor, NonFiniteLossError
from src.prepare import prepare_training
from tests.conftest import compose_config, identity_normalizer, refused, run_module
from tests.test_resume import TINY

# H3.6M's own datamodule on the synthetic files (subject 1 trains, S5 tests): unlike the
# synthetic module it never regenerates missing files, so deleting them is a real test.
H36M_ON_SYNTHETIC = [
    "data=h36m",
    "data.actions=[walking,eating,smoking]",
    "data.train_subjects=[1]",
]
SHORT = [o for o in TINY if not o.startswith(("data=", "iterations=", "val_every="))]


def _train(out: Path, data_dir: Path, *overrides: str, iterations: int = 2, val_every: int = 1):
    from src.train import train

    cfg = compose_config(
        "train",
        [
            *H36M_ON_SYNTHETIC,
            *SHORT,
            f"iterations={iterations}",
            f"val_every={val_every}",
            *overrides,
        ],
        out,
        data_dir,
    )
    return cfg, train(cfg)


@pytest.fixture(scope="module")
def h36m_dir(synthetic_data_dir) -> Path:
    return synthetic_data_dir / "synthetic"


@pytest.fixture(scope="module")
def trained(tmp_path_factory, h36m_dir) -> Path:
    """One short adversarial run (2 epochs of 1 iteration); returns its run folder."""
    out = tmp_path_factory.mktemp("trained") / "run"
    _train(out, h36m_dir)
    return out


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """Tiny networks: one thread is faster than two on a busy machine, and results do not
    depend on it (the determinism test compares runs made the same way)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _last(run: Path) -> dict:
    return torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)


# ------------------------------------------------------------------------------ determinism
def test_same_config_and_seed_give_identical_results(trained, h36m_dir, tmp_path):
    _train(tmp_path / "again", h36m_dir)
    first = OmegaConf.load(trained / "summary.yaml")
    second = OmegaConf.load(tmp_path / "again" / "summary.yaml")
    for key in ("best_val_euler_avg", "final_val_euler_avg", "final_val_mpjpe_avg", "iterations"):
        assert first[key] == second[key], key
    a, b = _last(trained), _last(tmp_path / "again")
    assert a["global_step"] == 2
    for name, tensor in a["state_dict"].items():
        assert torch.equal(tensor, b["state_dict"][name]), name


# ------------------------------------------------------------------------------ numerics
def _poison_data_at(iteration: int):
    """NaN targets from `iteration` on: the next loss is NaN."""
    original = MotionPredictor.training_step

    def step(self, batch, batch_idx):
        if self.global_step == iteration:  # D's windows and G's
            poisoned = lambda b: {**b, "future": b["future"] * float("nan")}  # noqa: E731
            batch = {**poisoned(batch), "d": poisoned(batch["d"])}
        return original(self, batch, batch_idx)

    return step


def _poison_weights_after(iteration: int):
    """NaN weights after a step whose loss was finite: only the checkpoint guard sees them."""
    original = MotionPredictor.training_step

    def step(self, batch, batch_idx):
        original(self, batch, batch_idx)
        if self.global_step == iteration:
            with torch.no_grad():
                for p in self.net.parameters():
                    p.fill_(float("nan"))

    return step


@pytest.mark.parametrize(
    ("poison", "message", "overrides"),
    [
        (_poison_data_at(3), r"non-finite loss at training iteration 3: \{'loss_d': nan\}", []),
        (_poison_weights_after(4), r"non-finite weights after training iteration 4", []),
        # Between validations: only the check before each checkpoint stands between the NaN
        # weights and the periodic save of iteration 3.
        (
            _poison_weights_after(3),
            r"non-finite weights after training iteration 3",
            ["checkpoint_every=1"],
        ),
    ],
    ids=["nan_loss", "nan_weights", "nan_weights_before_a_periodic_checkpoint"],
)
def test_non_finite_training_stops_and_keeps_last_good_checkpoint(
    poison, message, overrides, monkeypatch, h36m_dir, tmp_path
):
    monkeypatch.setattr(MotionPredictor, "training_step", poison)
    out = tmp_path / "run"
    with pytest.raises(NonFiniteLossError, match=message) as err:
        _train(out, h36m_dir, *overrides, iterations=4, val_every=2)
    # The message carries the last finite losses so the user sees the trend before the blow-up.
    assert "Last finite losses" in str(err.value) and "train/loss_g" in str(err.value)
    # The message names the file to resume from (issue: it used to point at a folder).
    assert f"The last good checkpoint is {out / 'checkpoints' / 'last.ckpt'}" in str(err.value)
    kept = _last(out)
    assert kept["global_step"] == 2  # epoch 0's, not overwritten
    assert all(
        torch.isfinite(t).all() for t in kept["state_dict"].values() if t.is_floating_point()
    )
    assert not (out / "summary.yaml").exists()


def test_divergence_before_any_checkpoint_says_there_is_none(monkeypatch, h36m_dir, tmp_path):
    monkeypatch.setattr(MotionPredictor, "training_step", _poison_data_at(0))
    with pytest.raises(NonFiniteLossError, match="No checkpoint was written before this point"):
        _train(tmp_path / "run", h36m_dir, iterations=4, val_every=2)
    assert not (tmp_path / "run" / "checkpoints" / "last.ckpt").exists()


def test_project_errors_become_one_line_and_exit_code_2(capsys):
    @hydra_entry("train", tidy=False)
    def run(cfg):
        raise NonFiniteLossError("non-finite loss at training iteration 7: {'loss_g': nan}")

    with pytest.raises(SystemExit) as exit_info:
        run(OmegaConf.create())
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err == "error: non-finite loss at training iteration 7: {'loss_g': nan}\n"


@pytest.mark.slow
def test_cli_exploding_learning_rate_reports_the_iteration(tmp_path, synthetic_data_dir):
    proc = run_module(
        "src.train",
        *[o for o in TINY if not o.startswith("adversarial.")],
        "adversarial=none",
        "model.optimizer.lr=1e30",  # the first Adam step moves every weight by about 1e30
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 2, proc.stderr[-3000:]
    (line,) = [x for x in proc.stderr.splitlines() if x.startswith("error:")]
    assert line.startswith("error: non-finite loss at training iteration 1: ")
    assert "Last finite losses (oldest first): [{'train/loss_g': " in line
    assert "Traceback" not in proc.stderr


# ------------------------------------------------------------------------------ mismatches
def _eval_cfg(ckpt: Path, out: Path, data_dir: Path, *overrides: str):
    return compose_config("eval", [f"ckpt_path={ckpt}", *overrides], out, data_dir)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["model=gru_s2s"], "architecture: checkpoint is conv_s2s, config asks for model=gru_s2s"),
        (["model=conv_s2s", "model.net.nf=4"], "architecture settings: nf=2 in checkpoint vs 4"),
        (["data=cmu"], "dataset: checkpoint was trained on h36m, config asks for data=cmu"),
    ],
)
def test_eval_refuses_a_checkpoint_of_another_model_or_dataset(
    overrides, message, trained, h36m_dir, tmp_path
):
    from src.results import build_for_evaluation

    cfg = _eval_cfg(trained / "checkpoints" / "last.ckpt", tmp_path, h36m_dir, *overrides)
    with pytest.raises(CheckpointError, match=message):
        build_for_evaluation(cfg)


def test_resume_with_other_actions_is_refused_before_training(trained, h36m_dir, tmp_path):
    out = tmp_path / "resume"
    with pytest.raises(CheckpointError, match=r"actions: checkpoint .* \['walking', 'eating', "):
        _train(
            out, h36m_dir, f"ckpt_path={trained}/checkpoints/last.ckpt", "data.actions=[walking]"
        )
    assert not (out / "checkpoints").exists()


def test_other_normalisation_or_pose_dimension_is_refused(trained):
    ckpt = read_checkpoint(trained / "checkpoints" / "last.ckpt")
    state = {k.removeprefix("normalizer."): v for k, v in ckpt["state_dict"].items()}
    same = Normalizer(state["mean"], state["std"], state["used"])
    check_normalizer(ckpt, same, "ck")  # its own statistics pass

    shifted = Normalizer(state["mean"] + 0.01, state["std"], state["used"])
    with pytest.raises(CheckpointError, match="normalisation statistics: checkpoint ck"):
        check_normalizer(ckpt, shifted, "ck")
    wider = Normalizer(state["mean"], state["std"] * 1.5, state["used"])
    with pytest.raises(CheckpointError, match="normalisation statistics"):
        check_normalizer(ckpt, wider, "ck")
    cmu_like = identity_normalizer(117)
    with pytest.raises(CheckpointError, match=r"pose dimension: checkpoint ck uses 54 of 99"):
        check_normalizer(ckpt, cmu_like, "ck")


class _NotTensors:
    pass


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("truncated", "cannot read checkpoint .*damaged"),
        ("text", "cannot read checkpoint"),
        ("foreign_lightning", "is not a checkpoint written by this project"),
        ("pickled_object", "cannot read checkpoint"),  # weights_only: no code runs on load
    ],
)
def test_damaged_or_foreign_checkpoint_gives_checkpoint_error(content, message, trained, tmp_path):
    path = tmp_path / "x.ckpt"
    good = (trained / "checkpoints" / "last.ckpt").read_bytes()
    if content == "truncated":
        path.write_bytes(good[: len(good) // 2])
    elif content == "text":
        path.write_text("epoch,loss\n1,0.5\n")
    elif content == "foreign_lightning":
        torch.save({"state_dict": {"layer.weight": torch.zeros(2)}, "epoch": 3}, path)
    else:
        torch.save({"state_dict": {}, "motion": _NotTensors()}, path)
    with pytest.raises(CheckpointError, match=message):
        read_checkpoint(path)


def test_a_folder_given_as_checkpoint_names_the_files_in_it(tmp_path):
    """ckpt_path=<run>/checkpoints used to suggest <run>/checkpoints/checkpoints/last.ckpt,
    a file that cannot exist."""
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    for name in ("best-epoch001.ckpt", "last.ckpt"):
        (run / "checkpoints" / name).write_bytes(b"")
    best, last = run / "checkpoints" / "best-epoch001.ckpt", run / "checkpoints" / "last.ckpt"
    for folder in (run, run / "checkpoints"):
        with pytest.raises(CheckpointError, match="is a folder") as info:
            read_checkpoint(folder)
        assert f"give a checkpoint file: {best} or {last}" in str(info.value)
        assert "checkpoints/checkpoints" not in str(info.value)
    with pytest.raises(CheckpointError, match=rf"is a folder; .* e.g. {tmp_path}/checkpoints/last"):
        read_checkpoint(tmp_path)  # no checkpoint anywhere: the layout of a run


def test_eval_needs_no_training_files(trained, h36m_dir, tmp_path):
    """The statistics travel in the checkpoint: evaluation of a copy holding only the S5 test
    files works, writes into its own outputs/eval/ folder and recreates no training file."""
    copy = tmp_path / "data"
    shutil.copytree(h36m_dir / "h3.6m" / "dataset" / "S5", copy / "h3.6m" / "dataset" / "S5")
    proc = run_module(
        "src.eval",
        f"ckpt_path={trained}/checkpoints/last.ckpt",
        f"paths.data_dir={copy}",
        "trainer=cpu",
        "trainer.enable_progress_bar=false",
        data_dir=copy,
        log_dir=tmp_path / "logs",
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    (results,) = (tmp_path / "logs" / "eval" / "runs").glob("*/*/results.json")
    assert "walking" in results.read_text()
    assert not (copy / "h3.6m" / "dataset" / "S1").exists()
    assert not list((tmp_path / "logs").glob("train"))


# ------------------------------------------------------------------------------ nothing lost
def test_a_folder_holding_a_run_is_never_reused(trained, h36m_dir):
    before = {p: p.read_bytes() for p in (trained / "checkpoints").glob("*.ckpt")}
    with pytest.raises(ConfigError, match="already holds another run; nothing was overwritten"):
        _train(trained, h36m_dir)
    assert {p: p.read_bytes() for p in (trained / "checkpoints").glob("*.ckpt")} == before


@pytest.mark.parametrize("task", ["train", "eval", "visualize"])
def test_each_entry_point_writes_into_its_own_folder(task, tmp_path):
    cfg = compose_config(task, [], tmp_path)
    run_dir = Path(str(cfg.hydra.run.dir))
    assert run_dir.parent.parent == tmp_path / task / "runs"
    assert run_dir.name[:2] == "20"  # a timestamp, new for every run


@pytest.mark.slow
def test_same_command_twice_gives_two_run_folders(tmp_path, synthetic_data_dir):
    args = [*TINY[:-2], "iterations=1", "val_every=1"]
    for _ in range(2):
        proc = run_module("src.train", *args, data_dir=synthetic_data_dir, log_dir=tmp_path)
        assert proc.returncode == 0, proc.stderr[-3000:]
    runs = sorted((tmp_path / "train" / "runs").glob("*/*"))
    assert len(runs) == 2
    assert all((run / "checkpoints" / "last.ckpt").exists() for run in runs)


# ------------------------------------------------------------------------------ config errors
@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        (["metrics.dim_rule=windows"], ["metrics.dim_rule='windows'", "future, window"]),
        (["model.lambda_2=-1"], ["model.lambda_2=-1", ">= 0"]),
        (["adversarial.lambda_adv=-0.1"], ["adversarial.lambda_adv=-0.1", ">= 0"]),
        (["adversarial.lambda_2=-1"], ["adversarial.lambda_2=-1", ">= 0"]),
        (["model.lr_decay_every=0"], ["model.lr_decay_every=0", ">= 1"]),
        (["model.lr_decay_gamma=0"], ["model.lr_decay_gamma=0", "(0, 1]"]),
        (["model.grad_clip_norm=-5"], ["model.grad_clip_norm=-5", "> 0"]),
        # the constructors' own refusals, from the objects built before the run starts
        (["sampling=linear", "sampling.steps=0"], ["sampling.steps=0", "positive"]),
        (["sampling=inverse_sigmoid", "sampling.k=0.5"], ["sampling.k=0.5", ">= 1"]),
        (["data.eval_protocol=srn"], ["data.eval_protocol 'srn'", "srnn, random"]),
    ],
)
def test_more_out_of_range_values_are_rejected(overrides, named, tmp_path, synthetic_data_dir):
    cfg = compose_config("train", ["data=synthetic", *overrides], tmp_path, synthetic_data_dir)
    with pytest.raises((ConfigError, DataError)) as err:
        prepare_training(cfg, [], {})
    refused(str(err.value), *named)


def test_misspelt_action_lists_the_valid_ones_before_training(h36m_dir, tmp_path):
    out = tmp_path / "run"
    with pytest.raises(DataError, match=r"unknown h36m action\(s\) \['walkin'\].*walking"):
        _train(out, h36m_dir, "data.actions=[walkin]")
    assert not (out / "checkpoints").exists()
