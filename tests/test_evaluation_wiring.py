"""How the LightningModule turns predictions into the reported errors, without the archives
(issue #27): a model whose output is known gives the known Euler error per horizon, and the
error reported for a trained model is that of its fully autoregressive prediction, whatever
the training's eta schedule (protocol 4.1, 6.4: evaluation never sees the future)."""

from __future__ import annotations

import lightning as L
import pytest
import torch

from src.build import build_datamodule, build_module
from src.metrics.euler_error import EulerAngleError
from src.prepare import compose_config

OBSERVED, FUTURE = 50, 25
# Predicted frame k lies (k + 1) * 40 ms after the last observed frame (protocol 4.3).
HORIZONS = {80: 1, 160: 3, 320: 7, 400: 9, 560: 13, 1000: 24}
JOINT = slice(6, 9)  # the exp-map of the first joint after the root: all three columns used
THETA = 0.2  # its rotation about x in the last observed frame, radians


def _trainer() -> L.Trainer:
    return L.Trainer(
        accelerator="cpu", logger=False, enable_progress_bar=False, enable_model_summary=False
    )


def _loader(batch: dict[str, torch.Tensor]):
    return torch.utils.data.DataLoader([batch], batch_size=None)


def _rotating_windows(normalizer, slopes: list[float], actions: list[int]):
    """One window per slope: a still pose, then a future in which one joint turns about x by
    `slope` radians per frame, every other column constant. Normalised, as batches are."""
    assert bool(normalizer.used[JOINT].all())
    pose = normalizer.mean.clone()
    pose[JOINT] = torch.tensor([THETA, 0.0, 0.0])
    observed, future = [], []
    for slope in slopes:
        frames = pose.repeat(FUTURE, 1)
        frames[:, JOINT.start] = THETA + slope * torch.arange(1, FUTURE + 1)
        observed.append(pose.repeat(OBSERVED, 1))
        future.append(frames)
    return {
        "observed": normalizer.normalize(torch.stack(observed)),
        "future": normalizer.normalize(torch.stack(future)),
        "action": torch.tensor(actions),
    }


@pytest.mark.parametrize("dim_rule", ["future", "window"])
def test_a_known_prediction_gives_the_known_error_per_horizon(
    tmp_path, synthetic_data_dir, dim_rule
):
    """Zero-velocity (the last observed frame, repeated) against a joint turning about x at c
    radians per frame: the exp-map (theta, 0, 0) has the Euler angles (-theta, 0, 0), so the
    error at predicted frame k is c * (k + 1) (protocol 4.1: the norm over the dimensions where
    the ground truth moves; the still joints add nothing). Per action, the mean over its
    windows; the average row, the mean over the actions present; an action without windows is
    absent, not zero. Reading the moving dimensions from the prediction (prediction and ground
    truth swapped) would find none (it is still) and report 0."""
    cfg = compose_config(
        "eval",
        ["data=synthetic", "model=zero_velocity", f"metrics.dim_rule={dim_rule}"],
        tmp_path / "eval",
        synthetic_data_dir,
    )
    dm = build_datamodule(cfg.data)
    dm.prepare_data()
    dm.setup("test")
    module = build_module(cfg, dm)
    walking, eating, smoking = (dm.actions.index(a) for a in ("walking", "eating", "smoking"))
    # walking: two windows (slopes 0.01 and 0.03, mean 0.02); eating: one (0.005).
    batch = _rotating_windows(dm.normalizer, [0.01, 0.03, 0.005], [walking, walking, eating])
    (results,) = _trainer().test(module, dataloaders=_loader(batch), verbose=False)

    expected = {"walking": 0.02, "eating": 0.005, "average": (0.02 + 0.005) / 2}
    for name, slope in expected.items():
        for ms, k in HORIZONS.items():
            key = f"test_euler/{name}/{ms:04d}ms"
            assert results[key] == pytest.approx(slope * (k + 1), abs=1e-5), key
    assert not [k for k in results if "smoking" in k], "an action without windows is absent"
    mean_over_horizons = sum(k + 1 for k in HORIZONS.values()) / len(HORIZONS)
    assert results["test/euler_avg"] == pytest.approx(
        expected["average"] * mean_over_horizons, abs=1e-5
    )


def _tiny(model: str) -> list[str]:
    if model == "conv_s2s":
        return ["model=conv_s2s", "model.net.nf=2", "model.net.d_z=8", "adversarial=none"]
    return ["model=gru_s2s", "model.net.hidden=16"]


@pytest.mark.parametrize("stage", ["validate", "test"])
@pytest.mark.parametrize("model", ["conv_s2s", "gru_s2s"])
def test_evaluation_cannot_see_the_future(tmp_path, synthetic_data_dir, model, stage):
    """A model trained with teacher forcing (eta = 0: the decoder fed the ground truth) is
    still evaluated fully autoregressively (protocol 6.4: eta = 1, dropout off): the reported
    error per action and horizon is that of the prediction made from the observed frames
    alone, in validation during training and in src.eval's test alike."""
    cfg = compose_config(
        "train",
        ["data=synthetic", "trainer=cpu", "sampling=teacher_forcing", *_tiny(model)],
        tmp_path / "run",
        synthetic_data_dir,
    )
    dm = build_datamodule(cfg.data)
    dm.prepare_data()
    dm.setup("fit")
    L.seed_everything(0, verbose=False)
    module = build_module(cfg, dm)
    assert module.eta_schedule(0) == 0.0
    loader = dm.val_dataloader()
    run = _trainer().validate if stage == "validate" else _trainer().test
    (results,) = run(module, dataloaders=loader, verbose=False)

    module.eval()
    own, leaked = (EulerAngleError(len(dm.actions), FUTURE) for _ in range(2))
    unnormalize = dm.normalizer.unnormalize
    with torch.no_grad():
        for batch in loader:
            observed, future, action = batch["observed"], batch["future"], batch["action"]
            alone = module.net(observed, FUTURE, action=action)
            teacher_forced = module.net(observed, FUTURE, action=action, future=future, eta=0.0)
            own.update(unnormalize(alone), unnormalize(future), action)
            leaked.update(unnormalize(teacher_forced), unnormalize(future), action)
    own, leaked = own.compute(), leaked.compute()
    prefix = "val" if stage == "validate" else "test"
    for i, action_name in enumerate(dm.actions):
        for ms, k in HORIZONS.items():
            key = f"{prefix}_euler/{action_name}/{ms:04d}ms"
            assert results[key] == pytest.approx(own[i, k].item(), rel=1e-5), key
    # The check can fail: fed the ground truth, the model's errors are other ones.
    assert not torch.allclose(own, leaked, rtol=1e-3)
