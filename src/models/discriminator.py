"""Action-conditioned sequence discriminator of Li et al. 2018, eq. (8), protocol §6.5.

    logit = FC_1( ReLU( FC_256( [ReLU(CEM_32(sequence)), one_hot(action)] ) ) )

The whole 75-frame sequence (50 observed + 25 future, real or predicted) is encoded by a
CEM with nf=32 (channels 128, 256, 256). The reference conditions only the discriminator
on the action label; the generator never sees it (protocol §6.3).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from src.models.conv_encoder import ConvEncoder, tf_init_


def one_hot_action(action: Tensor | None, num_actions: int, batch: int) -> Tensor:
    """Float one-hot (B, num_actions) of a LongTensor (B,), with readable errors."""
    if action is None:
        raise ValueError("this model is conditioned on the action: pass action=LongTensor (B,)")
    if action.shape != (batch,) or action.dtype != torch.long:
        raise ValueError(
            f"action must be a LongTensor of shape ({batch},), "
            f"got {action.dtype} {tuple(action.shape)}"
        )
    # Range checked on the CPU only (a GPU would sync; its labels come from the datamodule's own
    # action list) and not while tracing or compiling (export).
    checkable = action.device.type == "cpu"
    if batch and checkable and not (torch.jit.is_tracing() or torch.compiler.is_compiling()):
        lo, hi = int(action.min()), int(action.max())
        if lo < 0 or hi >= num_actions:
            raise ValueError(f"action ids must lie in [0, {num_actions}), got [{lo}, {hi}]")
    return F.one_hot(action, num_actions).float()


class Discriminator(nn.Module):
    """D(X_{1:t+T}, action) -> logit (B,); sigmoid(logit) = probability the sequence is real.
    pose_dim D (54 H3.6M, 70 CMU), num_actions (15, 8), seq_len judged frames (75); nf, d_z,
    kernel, padding, dropout: CEM settings (protocol §6.2, §6.7); d_fc hidden FC width (256 =
    8·nf in the reference)."""

    def __init__(
        self,
        pose_dim: int,
        num_actions: int,
        seq_len: int = 75,
        nf: int = 32,
        d_z: int = 512,
        d_fc: int = 256,
        kernel: tuple[int, int] = (2, 7),
        padding: str = "same",
        dropout: tuple[float, float, float] = (0.2, 0.2, 0.5),
    ):
        super().__init__()
        self.pose_dim, self.num_actions, self.seq_len = pose_dim, num_actions, seq_len
        self.encoder = ConvEncoder(seq_len, pose_dim, d_z, nf, kernel, padding, dropout)
        self.fc = nn.Linear(d_z + num_actions, d_fc)
        self.out = nn.Linear(d_fc, 1)
        tf_init_(self.fc)
        tf_init_(self.out)

    def forward(self, sequence: Tensor, action: Tensor) -> Tensor:
        """(B, seq_len, D), (B,) long -> logits (B,)."""
        h = torch.relu(self.encoder(sequence))
        h = torch.cat([h, one_hot_action(action, self.num_actions, h.shape[0]).to(h)], dim=1)
        return self.out(torch.relu(self.fc(h))).squeeze(1)
