"""src.models.dropout.Dropout: nn.Dropout's contract with TF's uniform-threshold masks."""

import pytest
import torch
from torch import nn

from src.models.dropout import Dropout


@pytest.mark.parametrize("p", [0.2, 0.5])
def test_keeps_one_minus_p_and_rescales_the_kept(p):
    torch.manual_seed(0)
    x = torch.full((1_000_000,), 3.0)
    y = Dropout(p).train()(x)
    kept = y != 0
    # Binomial std of the kept fraction is ~5e-4 here; 3e-3 is six of them.
    assert abs(kept.float().mean().item() - (1 - p)) < 3e-3
    torch.testing.assert_close(y[kept], torch.full_like(y[kept], 3.0 / (1 - p)))


@pytest.mark.parametrize("p", [0.2, 0.5, 0.8])
def test_bfloat16_inputs_keep_one_minus_p_as_float32_ones_do(p):
    """Under bf16-mixed the activations are bfloat16; a mask drawn in bfloat16 kept about 0.001
    too many elements (0.5 -> 0.501), several binomial standard deviations at this size. The
    mask is drawn in float32: the same elements are kept as for a float32 input."""
    n = 1 << 23  # binomial std of the kept fraction <= 1.8e-4; 5e-4 is about three of them
    torch.manual_seed(0)
    y16 = Dropout(p).train()(torch.ones(n, dtype=torch.bfloat16))
    torch.manual_seed(0)
    y32 = Dropout(p).train()(torch.ones(n))
    assert y16.dtype == torch.bfloat16
    assert abs((y16 != 0).double().mean().item() - (1 - p)) < 5e-4
    assert torch.equal(y16 != 0, y32 != 0)


def test_gradient_is_the_same_mask():
    torch.manual_seed(1)
    x = torch.randn(64, 50, requires_grad=True)
    y = Dropout(0.5).train()(x)
    (g,) = torch.autograd.grad(y.sum(), x)
    torch.testing.assert_close(g, (y.detach() != 0).float() / 0.5)


def test_eval_mode_and_edge_probabilities_behave_as_nn_dropout():
    x = torch.randn(8, 9)
    torch.testing.assert_close(Dropout(0.5).eval()(x), x)
    torch.testing.assert_close(Dropout(0.0).train()(x), x)
    assert torch.equal(Dropout(1.0).train()(x), nn.Dropout(1.0).train()(x))


def test_masks_follow_the_torch_seed():
    x = torch.ones(1000)
    drop = Dropout(0.3).train()
    torch.manual_seed(5)
    a = drop(x)
    torch.manual_seed(5)
    b = drop(x)
    c = drop(x)
    assert torch.equal(a, b)
    assert not torch.equal(b, c)
