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
    """Li et al.'s generator, in the normalised used-dimension space.

    pose_dim D (54 H3.6M, 70 CMU); num_actions unused (module docstring); C the short-term
    window (eq. 2, 20); nf, d_z (512), kernel, padding, dropout: the CEMs' settings (protocol
    §6.2, "valid" on CMU §6.7); decoder_dropout between the decoder's FC layers (keep 0.5);
    long_term=False the Table 5 ablation; observed_len 50 frames, the long-term encoder reads
    all but the last; reference_eta_offset the reference's off-by-one in eq. (10) (§6.4);
    d_dec the spatial decoder's hidden width (512, paper §3.2).
    """

    @staticmethod
    def check_arguments(C: int = 20, observed_len: int = 50, **_) -> None:
        """The checks that need no data (src.build.build_parts runs them first)."""
        if not 1 <= C <= observed_len:
            raise ValueError(
                f"C={C} must lie in [1, observed_len={observed_len}]: the short-term window "
                f"is cut from the observed frames"
            )

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
        self.check_arguments(C=C, observed_len=observed_len)
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

    def forward(self, observed: Tensor, future_len: int, action=None, future=None, eta=1.0):
        """(B, observed_len, D) -> (B, future_len, D). `future` (B, >= future_len, D), the
        ground truth, is mixed in by eq. (10) when eta < 1 (or is a tensor, see `mixes`)."""
        B = check_forward_inputs(
            observed, self.observed_len, self.pose_dim, future_len, future, eta
        )
        mix = mixes(future, eta)
        # eq. (3)'s first layer is linear in [z_l, z_s]: W [z_l; z_s] + b = (W_l z_l + b) +
        # W_s z_s, and z_l is the same at every step, so W_l z_l + b is computed once here.
        first, act, drop, out = self.decoder
        h_l, w_s = first.bias.expand(B, -1), first.weight  # no z_l: the Table 5 ablation
        if self.long_term:
            z_l = self.long_encoder(observed[:, : self.observed_len - 1])  # eq. (1)
            d = z_l.shape[1]
            h_l, w_s = F.linear(z_l, first.weight[:, :d], first.bias), first.weight[:, d:]
        window = observed[:, -self.C :]  # frames 50-C .. 49
        preds = []
        for k in range(future_len):
            z_s = self.short_encoder(window)  # eq. (4)
            h = act(h_l + F.linear(z_s, w_s))
            pred = out(drop(h) if drop.training else h) + window[:, -1]  # eq. (6), residual
            preds.append(pred)
            if k == future_len - 1:
                # The window after the last prediction is never read, so nothing is appended.
                # For the offset variant this is the step whose "next frame" future[:, T]
                # does not exist; skipping it changes no output and needs only T GT frames.
                break
            nxt = pred
            if mix:
                # eq. (10) with x_{t+k} = future[:, k]; the reference (§6.4) takes the next
                # step's target, future[:, k+1], leaking (1-eta) of it through the residual.
                nxt = eta * pred + (1.0 - eta) * future[:, k + int(self.reference_eta_offset)]
            window = torch.cat([window[:, 1:], nxt.unsqueeze(1)], dim=1)  # eq. (5)
        return torch.stack(preds, dim=1) if preds else observed.new_zeros(B, 0, self.pose_dim)


def mixes(future: Tensor | None, eta: float | Tensor) -> bool:
    """Whether decoding mixes in the ground truth (eq. 10). A tensor eta is never read on the
    host (a compiled step would stop at the branch, a GPU would sync): it always mixes, which
    at eta = 1 gives the prediction exactly (1 * x + 0 * gt = x)."""
    return future is not None and (isinstance(eta, Tensor) or eta != 1.0)


def check_forward_inputs(observed, observed_len, pose_dim, future_len, future, eta) -> int:
    """Check the common forward contract (models/__init__.py); returns the batch size B.
    observed_len=None accepts any number of observed frames (the baselines). A tensor eta is
    not read (see `mixes`): its caller checks the value."""
    shape, want = tuple(observed.shape), "T" if observed_len is None else observed_len
    if len(shape) != 3 or shape[2] != pose_dim or observed_len not in (None, shape[1]):
        raise ValueError(f"observed must be (B, {want}, {pose_dim}), got {shape}")
    if future_len < 0:
        raise ValueError(f"future_len must be >= 0, got {future_len}")
    B = shape[0]
    if future is not None and (
        (future.dim(), *future.shape[::2]) != (3, B, pose_dim) or future.shape[1] < future_len
    ):
        raise ValueError(
            f"future must be (B={B}, T>={future_len}, {pose_dim}), got {tuple(future.shape)}"
        )
    if not isinstance(eta, Tensor) and not 0.0 <= eta <= 1.0:
        raise ValueError(f"eta must lie in [0, 1] (1 = own predictions, 0 = ground truth): {eta}")
    return B
