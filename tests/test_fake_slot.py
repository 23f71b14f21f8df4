"""The discriminator's real and fake sequences, with `adversarial.reference_fake_slot` off (the
paper) and on (the reference code, protocol section 6.5).

Every frame of the batch holds its own frame index (observed frames 0..49, future 50..74), so a
sequence reads as the list of frames it is made of; through training_step, window i adds
WINDOW * i, so a sequence also tells which window it comes from. The reference's fake sample is
w[0..48], w[50], then the 25 predictions; its real sample is w[0..74] in both modes.
"""

from __future__ import annotations

from types import SimpleNamespace

import lightning as L
import pytest
import torch

from src.build import build_datamodule, build_module
from src.lit.predictor import MotionPredictor
from tests import objects
from tests.objects import TINY_CONV

OBSERVED, FUTURE = 50, 25
TRUE_FRAMES = list(range(OBSERVED + FUTURE))
# The slot of the last observed frame (49) holds the first future frame (50) in the reference.
REFERENCE_FAKE_PREFIX = [*range(OBSERVED - 1), OBSERVED]


WINDOW = 1000  # window i holds frame index + WINDOW * i (frame_batch with distinct=True)


def frame_batch(batch: int, dim: int, distinct: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    frames = torch.arange(OBSERVED + FUTURE, dtype=torch.float32)
    frames = frames.view(1, -1, 1).expand(batch, -1, dim).clone()
    if distinct:
        frames += WINDOW * torch.arange(batch, dtype=torch.float32).view(-1, 1, 1)
    return frames[:, :OBSERVED], frames[:, OBSERVED:]


def windows_of(sequence: torch.Tensor) -> tuple[list[int], torch.Tensor]:
    """(the window each sample of a sequence comes from, read from its first observed frame;
    the sequences with those offsets taken away)."""
    ids = torch.div(sequence[:, 0, 0], WINDOW, rounding_mode="floor")
    return [int(i) for i in ids], sequence - WINDOW * ids.view(-1, 1, 1)


def frames_of(sequence: torch.Tensor) -> list[int]:
    """The frame index held in each slot (all samples and dimensions agree)."""
    assert torch.equal(sequence, sequence[:1, :, :1].expand_as(sequence))
    return [int(v) for v in sequence[0, :, 0]]


@pytest.mark.parametrize("reference", [False, True])
def test_sequence_real_is_the_ground_truth_in_both_modes(reference):
    observed, future = frame_batch(2, 3)
    module = SimpleNamespace(reference_fake_slot=reference)
    real = MotionPredictor._sequence(module, observed, future)
    assert frames_of(real) == TRUE_FRAMES


@pytest.mark.parametrize("reference", [False, True])
def test_sequence_fake_moves_the_slot_only_with_the_switch(reference):
    observed, future = frame_batch(2, 3)
    prediction = -1 - torch.arange(FUTURE, dtype=torch.float32).view(1, -1, 1).expand(2, -1, 3)
    module = SimpleNamespace(reference_fake_slot=reference)
    fake = frames_of(MotionPredictor._sequence(module, observed, future, prediction))
    prefix = REFERENCE_FAKE_PREFIX if reference else list(range(OBSERVED))
    assert fake == prefix + [-1 - k for k in range(FUTURE)]
    # A prediction that happens to be a copy of the ground truth is still a fake sample.
    copy = MotionPredictor._sequence(module, observed, future, future.clone())
    assert frames_of(copy) == prefix + list(range(OBSERVED, OBSERVED + FUTURE))


@pytest.mark.parametrize("reference", [False, True])
def test_training_step_feeds_the_discriminator_these_sequence(train_cfg, reference):
    """Through training_step: the D step's real and fake samples and the G step's fake one."""
    cfg = train_cfg(
        *TINY_CONV,
        f"adversarial.reference_fake_slot={str(reference).lower()}",
    )
    L.seed_everything(0)
    dm = build_datamodule(cfg.data)
    dm.prepare_data()
    dm.setup("fit")
    module = build_module(cfg, dm)
    assert module.adversarial and module.reference_fake_slot is reference
    seen: list[torch.Tensor] = []
    module.discriminator.register_forward_pre_hook(
        lambda _, args: seen.append(args[0].detach().clone())
    )
    # Four different windows: two draws of two, one for the D step, one for the G step.
    observed, future = frame_batch(4, dm.normalizer.pose_dim, distinct=True)
    flat = {"observed": observed, "future": future, "action": torch.zeros(4, dtype=torch.long)}
    objects.fit_batches(module, [objects.with_d_windows(flat)])

    # The D step judges real and fake in one call: the first half real, the second fake.
    (real_and_fake, fake_g) = seen
    real_d, fake_d = real_and_fake.chunk(2)
    assert real_d.shape[0] == fake_d.shape[0] == fake_g.shape[0] == 2
    # Protocol 6.6: D judges the windows of one draw, real and predicted; the G step judges
    # its predictions for the windows of the other draw.
    (d_windows, real_d), (fake_d_windows, fake_d) = windows_of(real_d), windows_of(fake_d)
    g_windows, fake_g = windows_of(fake_g)
    assert fake_d_windows == d_windows
    assert sorted(d_windows + g_windows) == [0, 1, 2, 3], (d_windows, g_windows)
    assert frames_of(real_d) == TRUE_FRAMES
    prefix = REFERENCE_FAKE_PREFIX if reference else list(range(OBSERVED))
    for fake in (fake_d, fake_g):
        assert fake.shape[1] == OBSERVED + FUTURE
        assert frames_of(fake[:, :OBSERVED]) == prefix
    # Around the last observed frame (the slots of the issue: 46..52).
    assert frames_of(real_d[:, 46:53]) == [46, 47, 48, 49, 50, 51, 52]
    assert frames_of(fake_d[:, 46:50]) == ([46, 47, 48, 50] if reference else [46, 47, 48, 49])
