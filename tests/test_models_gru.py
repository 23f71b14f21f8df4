"""GRUSeq2Seq (Martinez et al. 2017, protocol §5): sizes, tying, residual, one-hot, decoder
inputs for eta in {0, 0.5, 1}, autoregressive decoding and gradients through the feedback."""

import pytest
import torch

from src.models import GRUSeq2Seq

D, A = 54, 15


def gru_params(inp: int, hidden: int) -> int:
    # nn.GRUCell: weight_ih (3H, I), weight_hh (3H, H), bias_ih (3H), bias_hh (3H)
    return 3 * hidden * (inp + hidden) + 6 * hidden


def n_params(model) -> int:
    return sum(p.numel() for p in model.parameters())


@pytest.mark.parametrize("one_hot", [True, False])
def test_tied_vs_untied_parameter_counts(one_hot):
    I = D + A if one_hot else D  # 69 with one-hot (protocol §5), 54 without
    proj = 1024 * I + I
    tied = GRUSeq2Seq(pose_dim=D, num_actions=A, one_hot=one_hot)
    untied = GRUSeq2Seq(pose_dim=D, num_actions=A, one_hot=one_hot, tied=False)
    assert tied.input_size == I and (tied.proj.in_features, tied.proj.out_features) == (1024, I)
    assert n_params(tied) == gru_params(I, 1024) + proj
    assert n_params(untied) == 2 * gru_params(I, 1024) + proj
    assert n_params(tied) == (3_363_840 if one_hot else 3_317_760) + proj
    assert tied.decoder is None and untied.decoder is not untied.encoder


def test_output_layer_init_is_uniform_004():
    torch.manual_seed(0)
    model = GRUSeq2Seq(pose_dim=D, num_actions=A)
    for t in (model.proj.weight, model.proj.bias):
        assert t.abs().max() <= 0.04 and t.abs().max() > 0.035  # fills the range


@pytest.mark.parametrize("one_hot", [True, False])
@pytest.mark.parametrize("tied", [True, False])
@pytest.mark.parametrize("residual", [True, False])
def test_shapes(one_hot, tied, residual):
    model = GRUSeq2Seq(
        pose_dim=70, num_actions=8, hidden=16, tied=tied, residual=residual, one_hot=one_hot
    )
    action = torch.tensor([0, 7, 3])
    out = model(torch.randn(3, 50, 70), 10, action=action)
    assert out.shape == (3, 10, 70)
    full = model.decode(torch.randn(3, 50, 70), 10, action=action)
    assert full.shape == (3, 10, 78 if one_hot else 70)


@pytest.mark.parametrize("one_hot", [True, False])
def test_residual_predicts_velocity(one_hot):
    # With a zero output layer the residual model is exactly the zero-velocity baseline
    # (output = input + 0, fed back), the plain model predicts zeros.
    observed, action = torch.randn(2, 50, D), torch.tensor([1, 2])
    for residual, expected in ((True, observed[:, 49:].expand(-1, 7, -1)), (False, None)):
        model = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=8, residual=residual, one_hot=one_hot)
        torch.nn.init.zeros_(model.proj.weight)
        torch.nn.init.zeros_(model.proj.bias)
        out = model(observed, 7, action=action)
        if expected is None:
            expected = torch.zeros(2, 7, D)
        torch.testing.assert_close(out, expected, rtol=0, atol=0)


def record_decoder_inputs(model, observed, future_len, **kw):
    """Inputs fed to the decoder GRU at each step, and the decoder outputs (decode)."""
    cell = model.decoder if model.decoder is not None else model.encoder
    seen = []
    hook = cell.register_forward_pre_hook(lambda _m, args: seen.append(args[0].detach().clone()))
    out = model.decode(observed, future_len, **kw)
    hook.remove()
    if model.decoder is None:  # tied: the first 49 calls are the encoder's
        seen = seen[model.observed_len - 1 :]
    return seen, out.detach()


@pytest.mark.parametrize("tied", [True, False])
@pytest.mark.parametrize("eta", [0.0, 0.5, 1.0])
def test_decoder_inputs_mix_own_output_and_ground_truth(tied, eta):
    torch.manual_seed(0)
    model = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=16, tied=tied).eval()
    observed, future = torch.randn(2, 50, D), torch.randn(2, 6, D)
    action = torch.tensor([4, 9])
    onehot = torch.zeros(2, A)
    onehot[0, 4] = onehot[1, 9] = 1.0
    seen, out = record_decoder_inputs(model, observed, 6, action=action, future=future, eta=eta)
    assert len(seen) == 6
    # step 0: frame 49 plus the one-hot, whatever eta
    torch.testing.assert_close(seen[0], torch.cat([observed[:, 49], onehot], 1), rtol=0, atol=0)
    for k in range(1, 6):
        gt = torch.cat([future[:, k - 1], onehot], 1)  # ground truth frame 49 + k
        torch.testing.assert_close(seen[k], eta * out[:, k - 1] + (1 - eta) * gt)
    if eta == 0.0:  # supervised: exactly the ground-truth frames
        for k in range(1, 6):
            torch.testing.assert_close(seen[k][:, :D], future[:, k - 1], rtol=0, atol=0)


def test_predicted_one_hot_is_fed_back():
    # [M] feeds back the *predicted* one-hot part (protocol §8): make the projection add 1 to
    # the one-hot columns only; the fed-back one-hot then grows by 1 per step.
    model = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=8, tied=False)
    torch.nn.init.zeros_(model.proj.weight)
    with torch.no_grad():
        model.proj.bias.zero_()
        model.proj.bias[D:] = 1.0
    seen, out = record_decoder_inputs(model, torch.randn(1, 50, D), 3, action=torch.tensor([2]))
    for k in range(3):
        expected = torch.full((A,), float(k))
        expected[2] += 1.0
        torch.testing.assert_close(seen[k][0, D:], expected, rtol=0, atol=0)
    assert out.shape == (1, 3, D + A)


def test_decoding_without_future_never_sees_ground_truth():
    torch.manual_seed(0)
    model = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=32).eval()
    observed, action = torch.randn(2, 50, D), torch.tensor([0, 1])
    f1, f2 = torch.randn(2, 10, D), torch.randn(2, 10, D)
    free = model(observed, 10, action=action)
    torch.testing.assert_close(model(observed, 10, action, f1, eta=1.0), free, rtol=0, atol=0)
    torch.testing.assert_close(model(observed, 10, action, f2, eta=1.0), free, rtol=0, atol=0)
    assert not torch.allclose(model(observed, 10, action, f1, eta=0.0), free)
    # Only frame 49 (and the history) seeds prediction 0; the future is not read.
    torch.testing.assert_close(model(observed, 10, action, f1, eta=0.0)[:, 0], free[:, 0])


def test_one_hot_requires_action():
    model = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=8)
    with pytest.raises(ValueError, match="pass action"):
        model(torch.randn(2, 50, D), 5)
    with pytest.raises(ValueError, match=r"action ids must lie in \[0, 15\)"):
        model(torch.randn(2, 50, D), 5, action=torch.tensor([0, 15]))
    with pytest.raises(ValueError, match=r"observed must be \(B, 50, 54\)"):
        model(torch.randn(2, 50, 70), 5, action=torch.tensor([0, 1]))
    # Without one-hot the action is ignored; different actions give identical outputs.
    plain = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=8, one_hot=False)
    x = torch.randn(2, 50, D)
    torch.testing.assert_close(plain(x, 3), plain(x, 3, action=torch.tensor([5, 6])))


def test_action_changes_the_prediction_with_one_hot():
    torch.manual_seed(0)
    model = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=16)
    x = torch.randn(1, 50, D).expand(2, -1, -1)
    out = model(x, 3, action=torch.tensor([0, 1]))
    assert not torch.allclose(out[0], out[1])


@pytest.mark.parametrize("tied", [True, False])
def test_gradients_reach_every_parameter(tied):
    torch.manual_seed(0)
    model = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=16, tied=tied)
    observed, future = torch.randn(2, 50, D), torch.randn(2, 10, D)
    out = model(observed, 10, action=torch.tensor([0, 3]), future=future, eta=0.5)
    (out - future).pow(2).mean().backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_gradient_flows_through_fed_back_outputs():
    # Non-residual: out_1 = W h_1 + b with h_1 = GRU(out_0, h_0), out_0 = W h_0' + b.
    # If the fed-back out_0 were detached (the PyTorch port [P]), d sum(out_1) / d b would be
    # exactly B for every column; with TF-style feedback it also gets the path through out_0.
    torch.manual_seed(0)
    model = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=16, residual=False, one_hot=False)
    out = model(torch.randn(2, 50, D), 2)
    out[:, 1].sum().backward()
    assert not torch.allclose(model.proj.bias.grad, torch.full((D,), 2.0))
    # ...and with teacher forcing (eta = 0) there is no such path.
    model.zero_grad()
    model(torch.randn(2, 50, D), 2, future=torch.randn(2, 2, D), eta=0.0)[:, 1].sum().backward()
    torch.testing.assert_close(model.proj.bias.grad, torch.full((D,), 2.0))
