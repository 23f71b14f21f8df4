"""ConvEncoder / ConvSeq2Seq / Discriminator: exact shapes (protocol §6.2, §6.7), TF padding,
eq. (10) mixing, autoregressive decoding and gradients."""

import pytest
import torch
from torch import nn

from src.models import ConvEncoder, ConvSeq2Seq, Discriminator
from src.models.conv_encoder import conv_shapes, tf_conv_geometry

# (in_len, pose_dim, nf, padding, per-layer (C, H, W), flattened) from protocol §6.2 and §6.7.
SHAPES = {
    "h36m-long": (49, 54, 16, "same", [(64, 25, 27), (128, 13, 14), (128, 7, 7)], 6272),
    "h36m-short": (20, 54, 16, "same", [(64, 10, 27), (128, 5, 14), (128, 3, 7)], 2688),
    "h36m-disc": (75, 54, 32, "same", [(128, 38, 27), (256, 19, 14), (256, 10, 7)], 17920),
    "cmu-long": (49, 70, 16, "valid", [(64, 24, 32), (128, 12, 13), (128, 6, 4)], 3072),
    "cmu-short": (20, 70, 16, "valid", [(64, 10, 32), (128, 5, 13), (128, 2, 4)], 1024),
    "cmu-disc": (75, 70, 32, "valid", [(128, 37, 32), (256, 18, 13), (256, 9, 4)], 9216),
}


def conv_output_shapes(encoder: ConvEncoder, x: torch.Tensor) -> list[tuple[int, ...]]:
    """Run the encoder and record the output shape of every Conv2d."""
    seen = []
    hooks = [
        m.register_forward_hook(lambda _m, _i, out: seen.append(tuple(out.shape)))
        for m in encoder.modules()
        if isinstance(m, nn.Conv2d)
    ]
    encoder(x)
    for h in hooks:
        h.remove()
    return seen


@pytest.mark.parametrize("case", list(SHAPES))
def test_cem_layer_shapes_match_protocol(case):
    in_len, D, nf, padding, layers, flat = SHAPES[case]
    enc = ConvEncoder(in_len, D, d_out=512, nf=nf, padding=padding)
    assert enc.shapes == layers
    assert enc.flat_dim == flat and enc.fc.in_features == flat
    assert conv_output_shapes(enc, torch.randn(2, in_len, D)) == [(2, *s) for s in layers]
    assert enc(torch.randn(3, in_len, D)).shape == (3, 512)


def test_cem_layers_follow_protocol_table():
    enc = ConvEncoder(49, 54)
    convs = [m for m in enc.modules() if isinstance(m, nn.Conv2d)]
    assert [c.out_channels for c in convs] == [64, 128, 128]
    assert all(c.kernel_size == (2, 7) and c.stride == (2, 2) and c.bias is None for c in convs)
    assert [m.p for m in enc.modules() if isinstance(m, nn.Dropout)] == [0.2, 0.2, 0.5]
    assert all(m.negative_slope == 0.2 for m in enc.modules() if isinstance(m, nn.LeakyReLU))
    assert enc.fc.bias is not None


def test_tf_same_padding_is_asymmetric():
    # TF SAME, hand-computed: 49 rows, k=2, s=2 -> 25 rows, 1 padding row at the bottom;
    # 54 cols, k=7, s=2 -> 27 cols, 5 padding cols: 2 left, 3 right.
    assert tf_conv_geometry(49, 2, 2, "same") == (25, 0, 1)
    assert tf_conv_geometry(54, 7, 2, "same") == (27, 2, 3)
    assert tf_conv_geometry(20, 2, 2, "same") == (10, 0, 0)
    assert tf_conv_geometry(49, 2, 2, "valid") == (24, 0, 0)
    assert tf_conv_geometry(70, 7, 2, "valid") == (32, 0, 0)


@pytest.mark.parametrize(
    "padding, pixel, expected",
    [
        # SAME: output (i, j) reads rows 2i..2i+1 and columns 2j-2..2j+4 (2 zero cols on the
        # left). Input pixel (48, 53): rows -> i = 24 (last, the bottom pad row is row 49);
        # cols 53 in [2j-2, 2j+4] -> j in {25, 26}.
        ("same", (48, 53), {(24, 25), (24, 26)}),
        # SAME: input (1, 4) -> i = 0 (a top pad row would move it to i = 1); col 4 in
        # [2j-2, 2j+4] -> j in {0..3} (a 3-col left pad would give {1..3}).
        ("same", (1, 4), {(0, 0), (0, 1), (0, 2), (0, 3)}),
        # VALID: output (i, j) reads rows 2i..2i+1, cols 2j..2j+6; row 48 is never read
        # (24 outputs cover rows 0..47).
        ("valid", (48, 10), set()),
        ("valid", (3, 10), {(1, 2), (1, 3), (1, 4), (1, 5)}),
    ],
)
def test_first_conv_receptive_field_matches_tf(padding, pixel, expected):
    enc = ConvEncoder(49, 54, padding=padding)
    pad, conv = enc.convs[0], enc.convs[1]
    with torch.no_grad():
        conv.weight.fill_(1.0)
    x = torch.zeros(1, 1, 49, 54)
    x[0, 0, pixel[0], pixel[1]] = 1.0
    out = conv(pad(x))[0, 0]  # every output channel has the same all-ones kernel
    assert {tuple(ix) for ix in (out != 0).nonzero().tolist()} == expected


@pytest.mark.filterwarnings("ignore:TF32 acceleration on top of oneDNN")  # flags() says it
@pytest.mark.parametrize("case", list(SHAPES))
def test_cem_gradients_equal_the_native_convolutions(case):
    """Outputs and gradients of the CEM (oneDNN convolutions on the CPU) equal PyTorch's
    native convolutions at every geometry of the protocol.

    Why this test exists: in torch 2.13.0+cpu, oneDNN's input gradient of a stride-2 2x7
    convolution that pads by itself is wrong for 128+ channels (30-40% relative error on a
    Sapphire Rapids CPU; the forward and weight gradients are right). The CEM pads with F.pad
    and convolves without padding, which is correct, and a change that moves the (symmetric)
    padding into the convolution to save the padded copy fails here."""
    if not torch.backends.mkldnn.is_available():
        pytest.skip("this torch build has no oneDNN: nothing to compare")
    in_len, D, nf, padding, *_ = SHAPES[case]
    torch.manual_seed(0)
    enc = ConvEncoder(in_len, D, nf=nf, padding=padding).eval()  # eval: no dropout
    x = torch.randn(3, in_len, D, requires_grad=True)
    params = [x, *enc.parameters()]

    def outputs_and_gradients():
        out = enc(x)
        return [out, *torch.autograd.grad(out.square().sum(), params)]

    onednn = outputs_and_gradients()
    with torch.backends.mkldnn.flags(enabled=False):
        native = outputs_and_gradients()
    for got, want in zip(onednn, native, strict=True):
        torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-5 * want.abs().max().item())


def test_cem_too_short_inputs_name_the_parameter():
    with pytest.raises(ValueError, match="in_len=5"):
        ConvEncoder(5, 70, padding="valid")
    with pytest.raises(ValueError, match="pose_dim=20"):
        ConvEncoder(49, 20, padding="valid")
    with pytest.raises(ValueError, match="padding='full'"):
        ConvEncoder(49, 54, padding="full")
    assert conv_shapes(8, 70, padding="valid")[-1][1] == 1  # the shortest valid window
    assert conv_shapes(1, 54, padding="same")[-1][1] == 1  # SAME never runs out
    with pytest.raises(ValueError, match=r"expects \(B, 49, 54\)"):
        ConvEncoder(49, 54)(torch.zeros(2, 50, 54))


def test_conv_s2s_constructor_validates_C():
    with pytest.raises(ValueError, match="C=5 is too small"):
        ConvSeq2Seq(pose_dim=70, num_actions=8, C=5, padding="valid")
    with pytest.raises(ValueError, match="C=51"):
        ConvSeq2Seq(pose_dim=54, num_actions=15, C=51)
    assert ConvSeq2Seq(pose_dim=70, num_actions=8, C=8, padding="valid").C == 8


@pytest.mark.parametrize(
    "D, A, padding, long_flat, short_flat",
    [(54, 15, "same", 6272, 2688), (70, 8, "valid", 3072, 1024)],
)
def test_conv_s2s_shapes(D, A, padding, long_flat, short_flat):
    model = ConvSeq2Seq(pose_dim=D, num_actions=A, padding=padding)
    assert model.C == 20
    assert model.long_encoder.in_len == 49  # frames 0..48 (protocol §6.1)
    assert model.long_encoder.flat_dim == long_flat
    assert model.short_encoder.flat_dim == short_flat
    dec = [m for m in model.decoder if isinstance(m, nn.Linear)]
    assert [(m.in_features, m.out_features) for m in dec] == [(1024, 512), (512, D)]
    out = model(torch.randn(2, 50, D), 25)
    assert out.shape == (2, 25, D)
    # The ablation without the long-term encoder (Table 5): decoder input 512.
    ablation = ConvSeq2Seq(pose_dim=D, num_actions=A, padding=padding, long_term=False)
    assert ablation.long_encoder is None
    assert ablation.decoder[0].in_features == 512
    assert ablation(torch.randn(2, 50, D), 10).shape == (2, 10, D)


@pytest.mark.parametrize("D, A, padding, flat", [(54, 15, "same", 17920), (70, 8, "valid", 9216)])
def test_discriminator_shapes(D, A, padding, flat):
    disc = Discriminator(pose_dim=D, num_actions=A, padding=padding)
    assert disc.encoder.shapes[0][0] == 128 and disc.encoder.flat_dim == flat
    assert (disc.fc.in_features, disc.fc.out_features) == (512 + A, 256)
    assert (disc.out.in_features, disc.out.out_features) == (256, 1)
    logits = disc(torch.randn(3, 75, D), torch.tensor([0, 1, A - 1]))
    assert logits.shape == (3,)


def test_discriminator_uses_action_and_checks_it():
    torch.manual_seed(0)
    disc = Discriminator(pose_dim=54, num_actions=15).eval()
    seq = torch.randn(1, 75, 54).expand(2, -1, -1)
    logits = disc(seq, torch.tensor([0, 7]))
    assert logits[0] != logits[1]  # same sequence, different action label
    with pytest.raises(ValueError, match=r"action ids must lie in \[0, 15\)"):
        disc(seq, torch.tensor([0, 15]))
    with pytest.raises(ValueError, match="LongTensor"):
        disc(seq, torch.tensor([0.0, 1.0]))
    with pytest.raises(ValueError, match="expects"):
        disc(torch.randn(2, 74, 54), torch.tensor([0, 1]))


# ---------------------------------------------------------------- eq. (10) mixing


class Recorder(nn.Module):
    """Stands in for the short-term encoder: records each window, returns a zero code."""

    def __init__(self, d_z):
        super().__init__()
        self.d_z, self.windows = d_z, []

    def forward(self, window):
        self.windows.append(window.detach().clone())
        return window.new_zeros(window.shape[0], self.d_z)


def scripted_model(offset=False, C=20, D=4):
    """The decoder's weights set so that it always outputs +1: x̂ = last window frame + 1 (eq. 6)."""
    model = ConvSeq2Seq(pose_dim=D, num_actions=1, C=C, reference_eta_offset=offset)
    model.short_encoder = Recorder(512)
    with torch.no_grad():
        for p in model.decoder.parameters():
            p.zero_()
        model.decoder[-1].bias.fill_(1.0)
    return model


def scalar_frames(values, D=4):
    """(1, T, D) tensor whose frame t has every entry equal to values[t]."""
    return torch.tensor(values, dtype=torch.float32)[None, :, None].expand(1, -1, D)


# Observed frame i has value i (0..49), ground-truth future frame k has value 100 + k.
# Hand-computed last values of the window seen before steps 1, 2, 3 (x̂ = last + 1):
#   eta 1:    50, 51, 52                               (own predictions)
#   eta 0:    100, 101, 102                            (ground truth, same time step)
#   eta 0.5:  m1 = .5*50 + .5*100 = 75; m2 = .5*76 + .5*101 = 88.5; m3 = .5*89.5 + .5*102 = 95.75
#   offset, eta 0.5 (GT of the NEXT step): .5*50 + .5*101 = 75.5; .5*76.5 + .5*102 = 89.25;
#                                          .5*90.25 + .5*103 = 96.625
@pytest.mark.parametrize(
    "eta, offset, appended",
    [
        (1.0, False, [50, 51, 52]),
        (0.0, False, [100, 101, 102]),
        (0.5, False, [75, 88.5, 95.75]),
        (1.0, True, [50, 51, 52]),
        (0.0, True, [101, 102, 103]),
        (0.5, True, [75.5, 89.25, 96.625]),
    ],
)
def test_eq10_mixing_feeds_the_right_frames(eta, offset, appended):
    model = scripted_model(offset)
    observed, future = scalar_frames(range(50)), scalar_frames([100, 101, 102, 103])
    out = model(observed, 4, future=future, eta=eta)
    windows = model.short_encoder.windows
    assert len(windows) == 4
    for k, window in enumerate(windows):  # window before step k: frames 30+k..49, then k mixed
        expected = scalar_frames(list(range(30 + k, 50)) + appended[:k])
        torch.testing.assert_close(window, expected, rtol=0, atol=0)
    expected_out = [49 + 1] + [v + 1 for v in appended]
    torch.testing.assert_close(out, scalar_frames(expected_out), rtol=0, atol=0)


def test_mixing_needs_no_frame_past_future_len():
    # Offset variant, T = 3: mixes use future[:, 1] and future[:, 2]; a future of exactly
    # future_len frames must suffice (the reference's unused mix after the last step is skipped).
    model = scripted_model(offset=True)
    out = model(scalar_frames(range(50)), 3, future=scalar_frames([100, 101, 102]), eta=0.0)
    torch.testing.assert_close(out, scalar_frames([50, 102, 103]), rtol=0, atol=0)
    with pytest.raises(ValueError, match="future must be"):
        model(scalar_frames(range(50)), 3, future=scalar_frames([100, 101]), eta=0.0)


def test_teacher_forcing_predicts_from_ground_truth_windows():
    # eta = 0 on the real network (ablation, so only the window matters): step k must equal a
    # fresh one-step prediction from the ground-truth window ending at frame 49 + k.
    torch.manual_seed(0)
    model = ConvSeq2Seq(pose_dim=54, num_actions=15, long_term=False).eval()
    observed, future = torch.randn(2, 50, 54), torch.randn(2, 5, 54)
    out = model(observed, 5, future=future, eta=0.0)
    full = torch.cat([observed, future], dim=1)
    for k in range(5):
        one_step = model(full[:, k : k + 50], 1)[:, 0]
        torch.testing.assert_close(out[:, k], one_step)


def test_decoding_without_future_never_sees_ground_truth():
    torch.manual_seed(0)
    model = ConvSeq2Seq(pose_dim=54, num_actions=15).eval()
    observed = torch.randn(2, 50, 54)
    f1, f2 = torch.randn(2, 8, 54), torch.randn(2, 8, 54)
    free = model(observed, 8)
    torch.testing.assert_close(model(observed, 8, future=f1, eta=1.0), free, rtol=0, atol=0)
    torch.testing.assert_close(model(observed, 8, future=f2, eta=1.0), free, rtol=0, atol=0)
    # ...while with eta < 1 the ground truth does matter (so the checks above can fail),
    # and only causally: prediction k uses ground truth up to frame k - 1.
    mixed1 = model(observed, 8, future=f1, eta=0.5)
    f3 = f1.clone()
    f3[:, 4:] += 1.0
    mixed3 = model(observed, 8, future=f3, eta=0.5)
    assert not torch.allclose(mixed1, free)
    torch.testing.assert_close(mixed1[:, :5], mixed3[:, :5], rtol=0, atol=0)
    assert not torch.allclose(mixed1[:, 5], mixed3[:, 5])
    # The reference offset leaks the target: prediction 4 already depends on future[:, 4].
    model.reference_eta_offset = True
    leak1, leak3 = model(observed, 8, future=f1, eta=0.5), model(observed, 8, future=f3, eta=0.5)
    torch.testing.assert_close(leak1[:, :4], leak3[:, :4], rtol=0, atol=0)
    assert not torch.allclose(leak1[:, 4], leak3[:, 4])


def test_forward_validates_inputs():
    model = ConvSeq2Seq(pose_dim=54, num_actions=15)
    with pytest.raises(ValueError, match=r"observed must be \(B, 50, 54\)"):
        model(torch.randn(2, 49, 54), 5)
    with pytest.raises(ValueError, match="eta must lie in"):
        model(torch.randn(2, 50, 54), 5, future=torch.randn(2, 5, 54), eta=1.5)


def test_gradients_reach_every_parameter():
    torch.manual_seed(0)
    model = ConvSeq2Seq(pose_dim=54, num_actions=15).train()
    disc = Discriminator(pose_dim=54, num_actions=15).train()
    observed, future = torch.randn(2, 50, 54), torch.randn(2, 25, 54)
    pred = model(observed, 25, future=future, eta=0.95)
    fake = torch.cat([observed, pred], dim=1)
    loss = (pred - future).pow(2).mean() + disc(fake, torch.tensor([3, 4])).sum()
    loss.backward()
    for module in (model, disc):
        for name, p in module.named_parameters():
            assert p.grad is not None and p.grad.abs().sum() > 0, name
