"""Residual GRU sequence-to-sequence model of Martinez et al. CVPR 2017 (paper §3.2, protocol §5).

    encoder:  h = GRU(x_i, h) for observed frames i = 0..48
    decoder:  step 0 input u_0 = frame 49; step k>0 input u_k = η·y_{k-1} + (1-η)·x_{49+k}
              h = GRU'(u_k, h);  y_k = W h + b (+ u_k if residual, "predict velocities")

η = 1 is the paper's sampling-based loss (the decoder always feeds its own output back, and
gradients flow through that feedback as in TensorFlow; the PyTorch port [P] detaches it,
protocol §8); η = 0 is the supervised / teacher-forced baseline. GRU' is the encoder's GRU
when `tied` (the paper's default, faster convergence) and a second GRU otherwise ("Untied");
the output projection W, b is shared in both cases ([M] seq2seq_model.py:131-140).

With `one_hot`, the 15-d (CMU: 8) action one-hot is appended to every input frame
("sup." models). As in [M], the one-hot columns are also projected, residual-added and fed
back, so the model predicts its own one-hot. Deviation: [M]'s loss also penalises those
columns; `forward` returns only the D pose columns, so our loss does not (`decode` returns
all columns if that loss is wanted).

Deviation: nn.GRUCell places the reset gate after the hidden matmul (r * (W_hn h + b_hn))
while TF's GRUCell applies it before (W (r * h)); initialisation of the GRU also follows
PyTorch rather than TF. The output layer keeps [M]'s uniform(-0.04, 0.04) init.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from src.models.conv_s2s import check_forward_inputs, mixes
from src.models.discriminator import one_hot_action


class GRUSeq2Seq(nn.Module):
    """Martinez et al.'s seq2seq, in the normalised used-dimension space: pose_dim D (54 H3.6M,
    70 CMU), num_actions (one-hot size), hidden GRU units (1024), tied, residual
    (`--residual_velocities`), one_hot ("sup." vs "unsup."), observed_len frames (50: 49 for
    the encoder, the last seeds the decoder)."""

    def __init__(
        self,
        pose_dim: int,
        num_actions: int,
        hidden: int = 1024,
        tied: bool = True,
        residual: bool = True,
        one_hot: bool = True,
        observed_len: int = 50,
    ):
        super().__init__()
        self.pose_dim, self.num_actions, self.hidden = pose_dim, num_actions, hidden
        self.tied, self.residual, self.one_hot = tied, residual, one_hot
        self.observed_len = observed_len
        self.input_size = pose_dim + (num_actions if one_hot else 0)

        self.encoder = nn.GRUCell(self.input_size, hidden)
        # Tied: the decoder *is* the encoder GRU; kept as None so checkpoints hold one copy.
        self.decoder = None if tied else nn.GRUCell(self.input_size, hidden)
        self.proj = nn.Linear(hidden, self.input_size)
        nn.init.uniform_(self.proj.weight, -0.04, 0.04)  # [M] rnn_cell_extensions.py:85-121
        nn.init.uniform_(self.proj.bias, -0.04, 0.04)

    def forward(self, observed: Tensor, future_len: int, action=None, future=None, eta=1.0):
        """Predict (B, future_len, D) pose frames; see `decode` for the arguments."""
        return self.decode(observed, future_len, action, future, eta)[..., : self.pose_dim]

    def decode(
        self,
        observed: Tensor,
        future_len: int,
        action: Tensor | None = None,
        future: Tensor | None = None,
        eta: float | Tensor = 1.0,
    ) -> Tensor:
        """All decoder outputs (B, future_len, input_size), one-hot columns included, of observed
        (B, observed_len, D); action (B,) long, required when one_hot; future (B, >= future_len,
        D) ground truth, mixed in when eta < 1 (see `mixes`)."""
        B = check_forward_inputs(
            observed, self.observed_len, self.pose_dim, future_len, future, eta
        )
        mix = mixes(future, eta)
        x, gt = observed, future
        if self.one_hot:
            oh = one_hot_action(action, self.num_actions, B).to(observed).unsqueeze(1)
            x = torch.cat([observed, oh.expand(-1, observed.shape[1], -1)], dim=2)
            if mix:
                gt = torch.cat([future, oh.expand(-1, future.shape[1], -1)], dim=2)

        h = observed.new_zeros(B, self.hidden)
        for t in range(self.observed_len - 1):  # frames 0..48; encoder outputs are discarded
            h = self.encoder(x[:, t], h)

        decoder = self.encoder if self.decoder is None else self.decoder
        inp = x[:, self.observed_len - 1]  # frame 49 seeds the decoder
        outs: list[Tensor] = []
        for k in range(future_len):
            if k > 0:
                inp = outs[-1]  # loop function: feed own output back, no detach
                if mix:
                    inp = eta * inp + (1.0 - eta) * gt[:, k - 1]  # GT frame 49+k
            h = decoder(inp, h)
            out = self.proj(h)
            outs.append(out + inp if self.residual else out)
        return torch.stack(outs, dim=1) if outs else observed.new_zeros(B, 0, self.input_size)
