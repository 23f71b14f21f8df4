"""Sampling boundaries and range checks, each at its edge (issue 41, point 3).

- The training sampler draws every valid start, the first and the last, and nothing beyond
  (protocol 1.4: H3.6M [16, n - 75), 1.5: CMU [0, n - 75), upper bound exclusive as the
  reference's randint), on a sequence with three valid starts; through the datamodule too.
- The test windows' start rules at theirs (protocol 3.1, 3.2) and the project's random and
  strided protocols.
- Every range check of a config value, of a constructor a config reaches, and of the
  user-facing calls: the value just inside is accepted (and builds), the value just outside
  is refused naming the key. A value that silently switches a mechanism off (a clip norm of
  0, a learning-rate factor of 0, a learning rate of 0) is among the refused ones.
"""

from __future__ import annotations

import copy
import itertools

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from src.data.datasets import TrainWindowSampler
from src.data.errors import DataError
from src.data.synthetic import SyntheticDataModule
from src.data.windows import cmu_test_starts, random_starts, srnn_h36m_starts, strided_starts
from src.inference import InferenceInputError, MotionForecaster
from src.lit.eta_schedule import Constant, InverseSigmoid, LinearRamp
from src.models import ConvSeq2Seq, Discriminator, ZeroVelocity
from src.visualize import select_window
from tests import objects
from tests.conftest import CONF, identity_normalizer

WINDOW = 75  # 50 observed + 25 future frames
LOW = {"h36m": 16, "cmu": 0}  # the first valid training start (protocol 1.4, 1.5)
TINY, ABOVE_ONE = 1e-12, 1.0 + 1e-9


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    yield from objects.one_thread()


# ------------------------------------------------------------------------------ sampling
def drawn_starts(lengths: list[int], low: int, batches: int = 40) -> set[tuple[int, int]]:
    sampler = TrainWindowSampler(lengths, WINDOW, low, batch_size=16)
    return {pair for k in range(batches) for pair in sampler.batch(k)}


@pytest.mark.parametrize("dataset", ["h36m", "cmu"])
def test_the_training_sampler_draws_the_first_and_last_valid_start_and_nothing_beyond(dataset):
    """A sequence of n frames has the valid starts low .. n - 76: 640 draws from one with three
    of them give exactly those three; n = low + 76 has one, n = low + 75 none (refused)."""
    low = LOW[dataset]
    n = low + WINDOW + 3
    assert drawn_starts([n], low) == {(0, low), (0, low + 1), (0, low + 2)}
    assert drawn_starts([low + WINDOW + 1], low) == {(0, low)}
    with pytest.raises(DataError, match="no training sequence is long enough"):
        TrainWindowSampler([low + WINDOW], WINDOW, low, batch_size=1)
    # A sequence too short beside a long one is never drawn; the long one still entirely.
    assert drawn_starts([low + WINDOW, n], low) == {(1, low), (1, low + 1), (1, low + 2)}


def even_rows(path) -> np.ndarray:
    """The raw text file's rows 0, 2, 4, ... (protocol 1.3: 25 fps)."""
    return np.loadtxt(path, delimiter=",", dtype=np.float32)[::2]


def test_the_datamodule_trains_on_every_valid_window_and_nothing_beyond(tmp_path):
    """Through the datamodule's training loader (H3.6M format, start from 16): two files of 94
    frames at 25 fps give exactly the six windows at starts 16, 17 and 18 of either file,
    each the file's even rows, normalised (320 draws)."""
    dm = SyntheticDataModule(
        tmp_path, actions=["walking"], raw_frames=2 * (LOW["h36m"] + WINDOW + 3),
        eval_protocol="random", eval_windows_per_action=2, batch_size=8,
    )  # fmt: skip
    dm.prepare_data()
    dm.setup("fit")
    files = sorted((tmp_path / "synthetic").rglob("S1/walking_*.txt"))
    assert len(files) == 2
    truth = []
    for path in files:
        frames = dm.normalizer.normalize(torch.from_numpy(even_rows(path)))
        assert len(frames) == LOW["h36m"] + WINDOW + 3
        truth += [frames[s : s + WINDOW] for s in range(LOW["h36m"], LOW["h36m"] + 3)]
    seen = [False] * len(truth)
    for batch in itertools.islice(dm.train_dataloader(), 40):
        for window in torch.cat([batch["observed"], batch["future"]], dim=1):
            match = [i for i, t in enumerate(truth) if torch.allclose(window, t, atol=1e-6)]
            assert len(match) == 1, "a training window that is no valid window of the files"
            seen[match[0]] = True
    assert all(seen), f"valid windows never drawn: {[i for i, s in enumerate(seen) if not s]}"


def test_the_test_window_rules_reach_their_last_start():
    """protocol 3.1: an H3.6M subaction of n frames gives starts in [16, n - 150), so 167 frames
    give only 16 and 166 are refused; 3.2: a CMU test file of n frames gives [0, n - 75), so
    76 frames give only 0 and 75 are refused. The random and strided protocols use the
    training range: 94 frames from 16 give 16, 17 and 18."""
    assert {s for _, s in srnn_h36m_starts(167, 167)} == {16}
    with pytest.raises(DataError, match="166 frames"):
        srnn_h36m_starts(166, 400)
    assert set(cmu_test_starts(76)) == {0}
    with pytest.raises(DataError, match="75 frames"):
        cmu_test_starts(75)
    assert {s for _, s in random_starts([94], 300, WINDOW, 16)} == {16, 17, 18}
    assert strided_starts([94], WINDOW, 1, 16) == [(0, 16), (0, 17), (0, 18)]
    assert strided_starts([WINDOW + 16], WINDOW, 1, 16) == []


# ------------------------------------------------------------------------------ config values
# (key, base, values accepted at the edge, values refused just beyond it)
CONFIG_RANGES = [
    ("iterations", "conv", [1], [0]),
    ("seed", "conv", [0, 2**32 - 1], [-1, 2**32]),
    ("checkpoint_every", "conv", [0], [-1]),
    ("val_every", "conv", [1], [0]),
    ("data.batch_size", "conv", [1], [0]),
    ("data.future_len", "conv", [1], [0]),
    ("model.optimizer.lr", "conv", [TINY], [0.0]),
    ("adversarial.optimizer.lr", "conv", [TINY], [0.0]),
    ("adversarial.lambda_adv", "conv", [0.0], [-TINY]),
    ("adversarial.lambda_2", "conv", [0.0], [-TINY]),
    ("model.lambda_2", "conv", [0.0], [-TINY]),
    ("model.net.C", "conv", [1, 50], [0, 51]),
    ("model.lr_decay_every", "conv", [1], [0]),
    ("model.lr_decay_gamma", "conv", [TINY, 1.0], [0.0, ABOVE_ONE]),
    ("model.grad_clip_norm", "conv", [TINY, None], [0.0, -1.0]),
    ("sampling.eta", "conv", [0.0, 1.0], [-TINY, ABOVE_ONE]),
    ("sampling.start", "linear", [0.0, 1.0], [-TINY, ABOVE_ONE]),
    ("sampling.end", "linear", [0.0, 1.0], [-TINY, ABOVE_ONE]),
    ("sampling.steps", "linear", [1], [0]),
    ("sampling.k", "inverse_sigmoid", [1.0], [1.0 - 1e-9]),
]


@pytest.fixture(scope="module")
def configs(tmp_path_factory, synthetic_data_dir):
    """The configs the ranges are checked on, and a synthetic datamodule to build on."""
    out = tmp_path_factory.mktemp("ranges")
    # val_every=1: every edge of `iterations` is then a whole number of validation periods.
    tiny = ["data=synthetic", "data.future_len=5", "model.net.nf=2", "model.net.d_z=8"]
    tiny.append("val_every=1")
    conv = objects.compose([*tiny, "adversarial=li2018"], out / "a", synthetic_data_dir)
    bases = {"conv": conv}
    for option in ("linear", "inverse_sigmoid"):
        cfg = copy.deepcopy(conv)
        cfg.sampling = OmegaConf.load(CONF / "sampling" / f"{option}.yaml")
        bases[option] = cfg
    return bases, objects.datamodule(conv.data)


def with_value(cfg, key: str, value):
    out = copy.deepcopy(cfg)
    OmegaConf.update(out, key, value, force_add=False)
    return out


@pytest.mark.parametrize(("key", "base", "inside", "outside"), CONFIG_RANGES, ids=str)
def test_each_config_range_check_accepts_its_edge_and_refuses_just_beyond(
    key, base, inside, outside, configs
):
    """src.train's checks, run before anything is built: the edge value passes them and the
    objects build with it; just beyond, a objects.ConfigError names the key."""
    bases, dm = configs
    for value in inside:
        cfg = with_value(bases[base], key, value)
        objects.validate(cfg)
        if key.startswith("data."):
            objects.datamodule(cfg.data, stage=None)
        else:
            objects.module(cfg, dm)
    for value in outside:
        cfg = with_value(bases[base], key, value)
        refused = (objects.ConfigError, objects.DataError)
        with pytest.raises(refused, match=key.replace(".", r"\.")):
            objects.validate(cfg)


# (data key, accepted at the edge, refused just beyond): checked by the datamodule itself.
DATA_RANGES = [
    ("observed_len", [1], [0]),
    ("future_len", [1, 100], [0, 101]),  # the SRNN windows reserve 150 frames (protocol 3.1)
    ("batch_size", [1], [0]),
    ("eval_batch_size", [1], [0]),
    ("eval_windows_per_action", [1], [0]),
    ("eval_stride", [1], [0]),
    ("eval_seed", [0, 2**32 - 1], [-1, 2**32]),
    ("num_workers", [0], [-1]),
    ("seed", [0], [-1]),
]


@pytest.mark.parametrize(("key", "inside", "outside"), DATA_RANGES, ids=str)
def test_each_datamodule_range_check_accepts_its_edge_and_refuses_just_beyond(
    key, inside, outside, configs
):
    bases, _ = configs
    for value in inside:
        objects.datamodule(with_value(bases["conv"], f"data.{key}", value).data, stage=None)
    for value in outside:
        cfg = with_value(bases["conv"], f"data.{key}", value)
        with pytest.raises((DataError, objects.ConfigError), match=key):
            objects.datamodule(cfg.data, stage=None)


def refused(call, error=ValueError, match=None) -> None:
    with pytest.raises(error, match=match):
        call()


def test_each_constructor_range_check_accepts_its_edge_and_refuses_just_beyond():
    """The checks of the classes the configs build (the eta schedules, the network), which
    guard them when built without src.train's checks."""
    for eta in (0.0, 1.0):
        assert Constant(eta)(0) == eta
    for eta in (-TINY, ABOVE_ONE):
        refused(lambda eta=eta: Constant(eta), match="sampling.eta")
    for key in ("start", "end"):
        for value in (0.0, 1.0):
            LinearRamp(**{key: value})
        for value in (-TINY, ABOVE_ONE):
            refused(lambda key=key, value=value: LinearRamp(**{key: value}), match=key)
    assert LinearRamp(0.0, 1.0, steps=1)(1) == 1.0
    refused(lambda: LinearRamp(steps=0), match="steps")
    InverseSigmoid(k=1.0)
    refused(lambda: InverseSigmoid(k=1.0 - 1e-9), match="k=")
    for C in (1, 50):
        assert ConvSeq2Seq(54, 3, C=C, nf=2, d_z=8)(torch.zeros(1, 50, 54), 1).shape == (1, 1, 54)
    for C in (0, 51):
        refused(lambda C=C: ConvSeq2Seq(54, 3, C=C, nf=2, d_z=8), match=f"C={C}")


def test_each_call_range_check_accepts_its_edge_and_refuses_just_beyond(configs):
    """eta of eq. (10) in [0, 1] and future_len >= 0 at the network; action ids in
    [0, actions) at the discriminator; future_len >= 1 and a whole multiple of 25 fps at the
    forecaster; the window of src.visualize in [0, windows of the action)."""
    net = ConvSeq2Seq(54, 3, C=5, nf=2, d_z=8)
    observed, future = torch.zeros(1, 50, 54), torch.zeros(1, 2, 54)
    for eta in (0.0, 1.0):
        net(observed, 2, future=future, eta=eta)
    for eta in (-TINY, ABOVE_ONE):
        refused(lambda eta=eta: net(observed, 2, future=future, eta=eta), match="eta must lie")
    assert net(observed, 0).shape == (1, 0, 54)
    refused(lambda: net(observed, -1), match="future_len")
    disc = Discriminator(54, 3, seq_len=52, nf=2, d_z=8, d_fc=4)
    sequences = torch.zeros(2, 52, 54)
    disc(sequences, torch.tensor([0, 2]))
    for bad in (-1, 3):
        refused(lambda bad=bad: disc(sequences, torch.tensor([0, bad])), match="action ids")

    normalizer = identity_normalizer(99)
    forecaster = MotionForecaster(ZeroVelocity(99, 1), normalizer, ["walking"])
    frames = np.zeros((100, 99), dtype=np.float32)
    assert forecaster.predict(frames[:50], future_len=1).shape == (1, 99)
    refused(lambda: forecaster.predict(frames[:50], future_len=0), InferenceInputError)
    forecaster.predict(frames[:50], fps=25)
    forecaster.predict(frames, fps=50)
    for fps in (0, 12.5, 50.01):
        refused(lambda fps=fps: forecaster.predict(frames, fps=fps), InferenceInputError, "fps")

    _, dm = configs
    action = dm.eval_windows[0].action
    count = sum(w.action == action for w in dm.eval_windows)
    assert dm.eval_windows[select_window(dm, action, count - 1)].action == action
    select_window(dm, action, 0)
    for window in (-1, count):
        refused(lambda w=window: select_window(dm, action, w), objects.ConfigError, "out of range")
