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
