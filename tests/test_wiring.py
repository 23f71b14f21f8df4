"""What reaches what in Li et al.'s network, the discriminator and the GRU (issue 41, point 1).

Checked against the paper (Li et al. 2018, Figure 2, eqs. 1-6 and 8) and the reference code
(protocol 6.1, 6.3, 6.5; Martinez et al.: protocol 5):

- the long-term encoder reads observed frames 0..48 (the reference's w[0..48], protocol 6.1
  and 10.1), the short-term encoder the last C observed frames 50-C..49 (eq. 2);
- the spatial decoder reads [z_l, z_s] in that order (eq. 3): its first layer's first d_z
  columns see the long-term code, the rest the short-term one; z_l is computed once;
- the discriminator judges each window's real and fake sequence with that window's own
  action (eq. 8, protocol 6.5);
- the GRU's encoder reads frames 0..48 in order and hands its state to the decoder, which
  starts from frame 49 (protocol 5).

Small networks, random weights, no data: a few seconds together.
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from src.models import ConvSeq2Seq, Discriminator, GRUSeq2Seq
from tests import objects

OBSERVED = 50


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    yield from objects.one_thread()


def conv_net(pose_dim=54, C=20, long_term=True, padding="same", d_z=8) -> ConvSeq2Seq:
    """A small Li et al. generator in eval mode (dropout off): weights are random."""
    torch.manual_seed(0)
    net = ConvSeq2Seq(
        pose_dim=pose_dim, num_actions=3, C=C, nf=2, d_z=d_z, padding=padding,
        long_term=long_term, dropout=(0.0, 0.0, 0.0), decoder_dropout=0.0, d_dec=16,
    )  # fmt: skip
    return net.eval()


def encoders(net: ConvSeq2Seq) -> tuple[nn.Module | None, nn.Module]:
    """(long-term encoder or None, short-term encoder): the CEMs of eq. (1) and eq. (2)."""
    return net.long_encoder, net.short_encoder


def decoder_layers(net: ConvSeq2Seq) -> tuple[nn.Linear, nn.Linear]:
    """The spatial decoder's two fully connected layers (paper 3.2: 1024 -> 512 -> D)."""
    first, second = [m for m in net.decoder.modules() if isinstance(m, nn.Linear)]
    return first, second


class Calls:
    """Inputs and outputs of every call of a module, recorded by forward hooks; with
    `replace`, the module's output is replaced by `replace(output)`."""

    def __init__(self, module: nn.Module, replace=None):
        self.inputs, self.outputs = [], []
        self.replace = replace
        self.handles = [
            module.register_forward_pre_hook(lambda _m, args: self.inputs.append(args[0].clone())),
            module.register_forward_hook(self._out),
        ]

    def _out(self, _m, _args, output):
        if self.replace is not None:
            output = self.replace(output)
        self.outputs.append(output.detach().clone())
        return output

    def remove(self):
        for h in self.handles:
            h.remove()


def perturbed(observed: torch.Tensor) -> torch.Tensor:
    """A batch of 1 + 50 sequences: `observed` (1, 50, D), then one copy per frame i with
    frame i moved."""
    batch = observed.repeat(OBSERVED + 1, 1, 1)
    for i in range(OBSERVED):
        batch[1 + i, i] += 3.0
    return batch


def moved(outputs: torch.Tensor) -> list[int]:
    """The frames whose move changed the output (row 0 is the unmoved sequence's)."""
    change = (outputs[1:] - outputs[:1]).flatten(1).abs().amax(1)
    return [i for i in range(OBSERVED) if change[i] > 1e-5 * (1 + outputs[0].abs().max())]


def frames_that_reach(net: ConvSeq2Seq, observed: torch.Tensor) -> tuple[list[int], list[int]]:
    """The observed frames whose change changes the long-term code, and those whose change
    changes the first short-term code, in a one-step prediction."""
    long_enc, short_enc = encoders(net)
    calls = Calls(long_enc), Calls(short_enc)
    with torch.no_grad():
        net(perturbed(observed), 1)
    for c in calls:
        c.remove()
    return moved(calls[0].outputs[0]), moved(calls[1].outputs[0])


def covered_rows(rows: int, padding: str, layers: int = 3) -> int:
    """How many leading rows (frames) of a CEM input its three 2x2-strided convolutions read
    (kernel height 2): all under SAME padding; under VALID (CMU, protocol 6.7) a layer whose
    input has an odd height drops its last row, as TF does (49 -> 24 -> 12 -> 6 reads 48
    frames, 20 -> 10 -> 5 -> 2 reads 16)."""
    if padding == "same":
        return rows
    heights = [rows]
    for _ in range(layers):
        heights.append((heights[-1] - 2) // 2 + 1)
    read = heights[-1]
    for _ in range(layers):
        read = 2 * read  # each output row reads 2 input rows, stride 2
    return read


# ---------------------------------------------------------------- encoders (eqs. 1, 2)
@pytest.mark.parametrize(
    "pose_dim, C, padding",
    [(54, 20, "same"), (70, 20, "valid"), (54, 5, "same"), (54, 50, "same"), (70, 10, "valid")],
)
def test_each_encoder_reads_the_frames_the_reference_gives_it(pose_dim, C, padding):
    """The long-term encoder receives observed frames 0..48 (protocol 6.1: the reference's
    w[0..48]; frame 49 reaches the model through the short-term window only), the first
    short-term window the last C frames 50-C..49 (eq. 2), each in their order, and z_l is
    computed once. Perturbing one observed frame changes each code exactly for the frames
    given to its encoder that its convolutions read: all of them under SAME padding (H3.6M);
    under VALID (CMU) the reference's geometry leaves out frame 48 of the long-term input and
    the last 4 of a 20-frame window (protocol 6.7's heights)."""
    net = conv_net(pose_dim, C, padding=padding)
    long_enc, short_enc = encoders(net)
    observed = torch.randn(1, OBSERVED, pose_dim)
    long_calls, short_calls = Calls(long_enc), Calls(short_enc)
    with torch.no_grad():
        net(observed, 3)
    assert len(long_calls.inputs) == 1, "z_l is computed once for the whole prediction (3.1)"
    torch.testing.assert_close(long_calls.inputs[0], observed[:, : OBSERVED - 1], rtol=0, atol=0)
    torch.testing.assert_close(short_calls.inputs[0], observed[:, OBSERVED - C :], rtol=0, atol=0)
    long_calls.remove()
    short_calls.remove()
    long_reach, short_reach = frames_that_reach(net, observed)
    assert long_reach == list(range(covered_rows(OBSERVED - 1, padding)))
    first = OBSERVED - C
    assert short_reach == list(range(first, first + covered_rows(C, padding)))


@pytest.mark.parametrize("C", [1, 7, 20])
def test_without_the_long_term_encoder_the_prediction_sees_the_last_c_frames_only(C):
    """Table 5's ablation: the decoder reads z_s alone, so the first predicted frame depends
    on exactly the frames of the first short-term window, 50-C..49 (no hook: the output)."""
    net = conv_net(C=C, long_term=False)
    with torch.no_grad():
        reach = moved(net(perturbed(torch.randn(1, OBSERVED, 54)), 1))
    assert reach == list(range(OBSERVED - C, OBSERVED))


# ---------------------------------------------------------------- spatial decoder (eqs. 3, 6)
def spatial_decoder(net: ConvSeq2Seq, code: torch.Tensor) -> torch.Tensor:
    """h_d of eq. (3) written from the paper (3.2): FC 512 with leaky ReLU (0.2, protocol
    6.3), then FC to one frame without activation; dropout is off in eval mode."""
    first, second = decoder_layers(net)
    return F.linear(F.leaky_relu(F.linear(code, first.weight, first.bias), 0.2), second.weight,
                    second.bias)  # fmt: skip


@pytest.mark.parametrize("long_term", [True, False])
def test_every_predicted_frame_is_the_decoder_of_z_l_then_z_s_plus_the_last_frame(long_term):
    """eq. (3) and (6): x̂_{t+k} = h_d([z_l, z_s(k)]) + the last frame of window k, with z_l
    first, the same z_l at every step, and z_s(k) the code of window k."""
    net = conv_net(long_term=long_term)
    long_enc, short_enc = encoders(net)
    observed = torch.randn(2, OBSERVED, 54)
    short_calls = Calls(short_enc)
    long_calls = Calls(long_enc) if long_term else None
    with torch.no_grad():
        prediction = net(observed, 4)
    assert len(short_calls.outputs) == 4
    for k in range(4):
        z_s, window = short_calls.outputs[k], short_calls.inputs[k]
        code = torch.cat([long_calls.outputs[0], z_s], dim=1) if long_term else z_s
        expected = spatial_decoder(net, code) + window[:, -1]
        torch.testing.assert_close(prediction[:, k], expected, msg=f"step {k}")


@pytest.mark.parametrize("zeroed", ["long", "short"])
def test_a_zeroed_code_removes_exactly_its_own_columns_of_the_decoder_input(zeroed):
    """With one encoder's code zeroed, the decoder's first-layer columns that code feeds
    (z_l: the first d_z, z_s: the last d_z, eq. 3) no longer matter and the other ones do."""
    d_z = 8
    net = conv_net(d_z=d_z)
    long_enc, short_enc = encoders(net)
    first, _ = decoder_layers(net)
    Calls(long_enc if zeroed == "long" else short_enc, replace=torch.zeros_like)
    observed = torch.randn(2, OBSERVED, 54)
    columns = {"long": slice(0, d_z), "short": slice(d_z, 2 * d_z)}
    other = "short" if zeroed == "long" else "long"
    with torch.no_grad():
        base = net(observed, 3)
        for block, matters in ((zeroed, False), (other, True)):
            saved = first.weight.clone()
            first.weight[:, columns[block]] += torch.randn_like(first.weight[:, columns[block]])
            moved = net(observed, 3)
            first.weight.copy_(saved)
            assert torch.equal(moved, base) != matters, (
                f"with z_{zeroed[0]} zeroed, the columns of z_{block[0]} "
                f"{'do not matter' if matters else 'still matter'}"
            )


# ---------------------------------------------------------------- discriminator (eq. 8)
def test_the_discriminator_judges_each_sequence_with_its_own_action():
    """eq. (8), protocol 6.5: D's logit for a sequence depends on that sequence's action
    label, not on the labels of the other sequences of its batch."""
    torch.manual_seed(0)
    disc = Discriminator(pose_dim=54, num_actions=5, nf=2, d_z=8, d_fc=4).eval()
    sequences, actions = torch.randn(4, 75, 54), torch.tensor([0, 3, 1, 4])
    logits = disc(sequences, actions)
    for i in range(4):
        torch.testing.assert_close(disc(sequences[i : i + 1], actions[i : i + 1])[0], logits[i])
        other = actions.clone()
        other[i] = (other[i] + 1) % 5
        changed = disc(sequences, other)
        assert changed[i] != logits[i], f"the logit of sequence {i} ignores its action"
        keep = [j for j in range(4) if j != i]
        torch.testing.assert_close(changed[keep], logits[keep], rtol=0, atol=0)


WINDOW = 1000.0  # window w's frames hold frame index + WINDOW * w (see tests/test_fake_slot.py)


def test_a_training_step_gives_the_discriminator_each_windows_own_action(
    tmp_path, synthetic_data_dir
):
    """eq. (8) through a training iteration: in the D step the real and the fake sequence of
    a window are judged with that window's action, and so is the G step's fake sequence
    (four windows of different actions, two draws of two)."""
    cfg = objects.compose(
        ["data=synthetic", "data.future_len=5", *objects.TINY_CONV], tmp_path / "run",
        synthetic_data_dir,
    )  # fmt: skip
    dm = objects.datamodule(cfg.data)
    built = objects.module(cfg, dm)
    _, disc = objects.networks(built)
    seen: list[tuple[torch.Tensor, torch.Tensor]] = []  # (sequences, actions) of each call

    def record(_m, args, kwargs):
        sequences, actions = (list(args) + [kwargs.get("sequence"), kwargs.get("action")])[:2]
        seen.append((sequences.detach().clone(), actions.clone()))

    disc.register_forward_pre_hook(record, with_kwargs=True)
    D, T = dm.pose_dim, dm.future_len
    frames = torch.arange(OBSERVED + T, dtype=torch.float32).view(1, -1, 1).expand(4, -1, D)
    frames = frames + WINDOW * torch.arange(4.0).view(-1, 1, 1)
    action_of = torch.tensor([0, 1, 2, 1])  # windows 0, 1 are one draw; 2, 3 the other
    batch = {"observed": frames[:, :OBSERVED], "future": frames[:, OBSERVED:], "action": action_of}
    objects.train_steps(built, [batch])
    judged = {"real": 0, "fake": 0}
    for sequences, actions in seen:
        windows = torch.div(sequences[:, 0, 0], WINDOW, rounding_mode="floor").long()
        assert actions.tolist() == action_of[windows].tolist(), (
            f"sequences of windows {windows.tolist()} judged with actions {actions.tolist()}"
        )
        for w, sequence in zip(windows, sequences, strict=True):
            judged["real" if torch.equal(sequence, frames[w]) else "fake"] += 1
    # The D step's real and fake sequences (2 + 2) and the G step's fake ones (2).
    assert judged == {"real": 2, "fake": 4}, judged


# ---------------------------------------------------------------- the GRU (protocol 5)
@pytest.mark.parametrize("tied", [True, False])
@pytest.mark.parametrize("one_hot", [True, False])
def test_the_gru_encodes_frames_0_to_48_and_hands_its_state_to_the_decoder(tied, one_hot):
    """Martinez et al. (protocol 5): the encoder consumes frames 0..48 in order, each with the
    sample's own action one-hot when `one_hot`; the decoder starts from the encoder's last
    state with frame 49 as its first input."""
    torch.manual_seed(0)
    A, D = 4, 6
    net = GRUSeq2Seq(pose_dim=D, num_actions=A, hidden=8, tied=tied, one_hot=one_hot).eval()
    observed, action = torch.randn(2, OBSERVED, D), torch.tensor([3, 1])
    cells = [m for m in net.modules() if isinstance(m, nn.GRUCell)]
    assert len(cells) == (1 if tied else 2)
    calls = []  # (cell, input, state in, state out), in call order
    for cell in cells:
        cell.register_forward_hook(
            lambda m, args, out: calls.append((m, args[0].clone(), args[1].clone(), out.clone()))
        )
    with torch.no_grad():
        net(observed, 3, action=action)
    extra = F.one_hot(action, A).float() if one_hot else torch.zeros(2, 0)
    frame = lambda t: torch.cat([observed[:, t], extra], dim=1)  # noqa: E731
    encoder_calls, decoder_calls = calls[: OBSERVED - 1], calls[OBSERVED - 1 :]
    assert len(decoder_calls) == 3
    assert len({id(c[0]) for c in encoder_calls}) == 1
    for t, (_, inp, _, _) in enumerate(encoder_calls):
        torch.testing.assert_close(inp, frame(t), rtol=0, atol=0, msg=f"encoder input {t}")
    torch.testing.assert_close(encoder_calls[0][2], torch.zeros(2, 8), rtol=0, atol=0)
    for (_, _, _, out), (_, _, h_in, _) in zip(encoder_calls, calls[1:], strict=False):
        torch.testing.assert_close(h_in, out, rtol=0, atol=0)  # each state carries over
    decoder_cell, first_input, first_state, _ = decoder_calls[0]
    assert (decoder_cell is encoder_calls[0][0]) == tied
    torch.testing.assert_close(first_input, frame(OBSERVED - 1), rtol=0, atol=0)
    torch.testing.assert_close(first_state, encoder_calls[-1][3], rtol=0, atol=0)
