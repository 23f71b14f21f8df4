"""Convolutional sequence-to-sequence predictor of Li et al. CVPR 2018 (paper §3.1).

    z_l      = CEM_l(observed frames 0..48)                          eq. (1)
    z_s(k)   = CEM_s(window of the last C frames before step k)      eq. (2), (4)
    x̂_{t+k}  = h_d([z_l, z_s(k)]) + last frame of the window         eq. (3), (6)
    window  <- window[1:] + [η·x̂_{t+k} + (1-η)·x_{t+k}]              eq. (5), (10)

Long-term input (protocol §6.1, §10.1): the paper's figure feeds X_{1:t} (all 50 observed
frames) to the long-term encoder, the reference code feeds frames 0..48 (49 frames) and the
last observed frame 49 only reaches the model through the short-term window. We follow the
code, so the published shapes (49x54 -> 6272 features) and numbers stay comparable.

Action labels: the reference long-term FC outputs 512 + 15 (CMU: 8) units, the extra ones
being class logits whose cross-entropy is logged but never optimised (protocol §6.3). They
change nothing, so they are omitted here; the generator receives no action label.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from src.models.conv_encoder import ConvEncoder, conv_shapes, tf_init_
from src.models.dropout import Dropout


class ConvSeq2Seq(nn.Module):
    """Li et al.'s generator. All tensors live in the normalised used-dimension space.

    Args:
        pose_dim: D, pose dimensions (54 H3.6M, 70 CMU).
        num_actions: number of action classes; unused (see module docstring), kept for the
            common constructor contract.
        C: short-term window size (eq. 2), 20 in the reference.
        nf: CEM base filter count (channels 4nf, 8nf, 8nf).
        d_z: size of each code z_l, z_s (512).
        kernel, padding, dropout: CEM settings (protocol §6.2; padding "valid" on CMU §6.7).
        decoder_dropout: drop probability between the decoder's two FC layers (keep 0.5).
        long_term: False is the Table 5 ablation without the long-term encoder.
        observed_len: observed frames (50); the long-term encoder reads the first
            observed_len - 1 of them.
        reference_eta_offset: reproduce the reference's off-by-one in eq. (10) (§6.4).
        d_dec: hidden width of the spatial decoder (512, paper §3.2).
    """

    def __init__(
        self,
        pose_dim: int,
        num_actions: int,
        C: int = 20,
        nf: int = 16,
        d_z: int = 512,
        kernel: tuple[int, int] = (2, 7),
        padding: str = "same",
        long_term: bool = True,
        dropout: tuple[float, float, float] = (0.2, 0.2, 0.5),
        decoder_dropout: float = 0.5,
        observed_len: int = 50,
        reference_eta_offset: bool = False,
        d_dec: int = 512,
    ):
        super().__init__()
        if not 1 <= C <= observed_len:
            raise ValueError(
                f"C={C} must lie in [1, observed_len={observed_len}]: the short-term window "
                f"is cut from the observed frames"
            )
        try:
            conv_shapes(C, pose_dim, nf, tuple(kernel), padding)
        except ValueError as e:
            raise ValueError(f"C={C} is too small for the short-term CEM: {e}") from e
        self.pose_dim, self.num_actions = pose_dim, num_actions
        self.C, self.observed_len = C, observed_len
        self.long_term, self.reference_eta_offset = long_term, reference_eta_offset

        cem = dict(d_out=d_z, nf=nf, kernel=kernel, padding=padding, dropout=dropout)
        # eq. (1): long-term encoder over frames 0..observed_len-2 (protocol §6.1)
        self.long_encoder = ConvEncoder(observed_len - 1, pose_dim, **cem) if long_term else None
        # eq. (2): short-term encoder over the sliding window of C frames
        self.short_encoder = ConvEncoder(C, pose_dim, **cem)
        # eq. (3): spatial decoder, 1024 -> 512 -> D (512 -> 512 -> D without z_l)
        self.decoder = nn.Sequential(
            nn.Linear(2 * d_z if long_term else d_z, d_dec),
            nn.LeakyReLU(0.2),
            Dropout(decoder_dropout),
            nn.Linear(d_dec, pose_dim),
        )
        tf_init_(self.decoder)

    def forward(
        self,
        observed: Tensor,
        future_len: int,
        action: Tensor | None = None,
        future: Tensor | None = None,
        eta: float | Tensor = 1.0,
    ) -> Tensor:
        """Predict (B, future_len, D) from observed (B, observed_len, D).

        `future` (B, >= future_len, D) is the ground truth, used only for the eq. (10) mixing
        when eta < 1; with future=None decoding is fully autoregressive. `action` is ignored.
        A 0-dim tensor eta (the compiled training step) always mixes: exact at eta = 1.
        """
        B = check_forward_inputs(
            observed, self.observed_len, self.pose_dim, future_len, future, eta
        )
        mix = mixes(future, eta)
        z_l = self.long_encoder(observed[:, : self.observed_len - 1]) if self.long_term else None
        decoder = self._decoder(z_l, B)
        window = observed[:, -self.C :]  # frames 50-C .. 49
        preds = []
        for k in range(future_len):
            z_s = self.short_encoder(window)  # eq. (4)
            pred = decoder(z_s) + window[:, -1]  # eq. (6), residual on the last frame
            preds.append(pred)
            if k == future_len - 1:
                # The window after the last prediction is never read, so nothing is appended.
                # For the offset variant this is the step whose "next frame" future[:, T]
                # does not exist; skipping it changes no output and needs only T GT frames.
                break
            nxt = self._next_frame(pred, future, k, eta) if mix else pred
            window = torch.cat([window[:, 1:], nxt.unsqueeze(1)], dim=1)  # eq. (5)
        return torch.stack(preds, dim=1) if preds else observed.new_zeros(B, 0, self.pose_dim)

    def _decoder(self, z_l: Tensor | None, batch: int):
        """The spatial decoder of eq. (3) as a function of z_s, for one sequence.

        Its first layer is linear in [z_l, z_s]: W [z_l; z_s] + b = (W_l z_l + b) + W_s z_s,
        and z_l is the same at every future step, so W_l z_l + b is computed once here instead
        of at each of the 25 steps (the same numbers up to float rounding).
        """
        first, act, drop, out = self.decoder
        d_l = 0 if z_l is None else z_l.shape[1]
        h_l = (
            first.bias.expand(batch, -1)
            if z_l is None
            else F.linear(z_l, first.weight[:, :d_l], first.bias)
        )
        w_s = first.weight[:, d_l:]

        def decoder(z_s: Tensor) -> Tensor:
            h = act(h_l + F.linear(z_s, w_s))
            return out(drop(h) if drop.training else h)

        return decoder

    def _next_frame(self, pred: Tensor, future: Tensor, k: int, eta: float | Tensor) -> Tensor:
        """eq. (10): mix x̂_{t+k} with its own ground truth x_{t+k} = future[:, k].

        The reference (protocol §6.4) uses w[51+it] = future[:, k+1], the target of the
        next step, which leaks (1-eta) of that target through the residual."""
        gt = future[:, k + 1] if self.reference_eta_offset else future[:, k]
        return eta * pred + (1.0 - eta) * gt


def mixes(future: Tensor | None, eta: float | Tensor) -> bool:
    """Whether decoding mixes in the ground truth (eq. 10). A tensor eta is never read on the
    host (a compiled step would stop at the branch, a GPU would sync): it always mixes, which
    at eta = 1 gives the prediction exactly (1 * x + 0 * gt = x)."""
    return future is not None and (isinstance(eta, Tensor) or eta != 1.0)


def check_forward_inputs(
    observed: Tensor,
    observed_len: int | None,
    pose_dim: int,
    future_len: int,
    future: Tensor | None,
    eta: float | Tensor,
) -> int:
    """Validate the common predictor forward contract; returns the batch size B.

    observed_len=None accepts any number of observed frames (the baselines). A tensor eta is
    not read (see `mixes`): its caller checks the value.
    """
    T = observed.shape[1] if observed.dim() == 3 and observed_len is None else observed_len
    if observed.dim() != 3 or tuple(observed.shape[1:]) != (T, pose_dim):
        want = "T" if observed_len is None else observed_len
        raise ValueError(f"observed must be (B, {want}, {pose_dim}), got {tuple(observed.shape)}")
    if future_len < 0:
        raise ValueError(f"future_len must be >= 0, got {future_len}")
    B = observed.shape[0]
    if future is not None and (
        future.dim() != 3
        or future.shape[0] != B
        or future.shape[2] != pose_dim
        or future.shape[1] < future_len
    ):
        raise ValueError(
            f"future must be (B={B}, T>={future_len}, {pose_dim}), got {tuple(future.shape)}"
        )
    if not isinstance(eta, Tensor) and not 0.0 <= eta <= 1.0:
        raise ValueError(f"eta must lie in [0, 1] (1 = own predictions, 0 = ground truth): {eta}")
    return B
