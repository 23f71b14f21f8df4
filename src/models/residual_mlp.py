"""A per-frame residual MLP: the worked example of docs/extending.md, and a small baseline.

Each decoder step predicts the next frame from the last C frames through one hidden layer, as a
change of the newest frame (Martinez et al. §4, "residual architecture": the network predicts
velocities):

    y_k = u_k + W_2 relu(W_1 [u_{k-C+1}; ...; u_k] + b_1) + b_2

The window slides over the observed frames and then over its own predictions: u_0 is frame 49,
and the frame entering the window after step k is eta y_k + (1 - eta) x_{50+k}, the ground truth
mixed in as in Li et al. eq. (10) (eta = 1 at evaluation). W_2 and b_2 start at zero, so the
untrained model is the zero-velocity baseline. No action label and no recurrence: what it gains
over zero-velocity is what the last C frames alone tell about the next one.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from src.models.conv_s2s import check_forward_inputs, mixes


class ResidualMLP(nn.Module):
    """Args: pose_dim D; num_actions (unused: the model takes no action label); C frames of
    context (10: 400 ms); hidden units of the one hidden layer."""

    def __init__(self, pose_dim: int, num_actions: int, C: int = 10, hidden: int = 256):
        super().__init__()
        if C < 1 or hidden < 1:
            raise ValueError(f"C={C} and hidden={hidden} must be >= 1")
        self.pose_dim, self.num_actions, self.C = pose_dim, num_actions, C
        self.mlp = nn.Sequential(
            nn.Linear(C * pose_dim, hidden), nn.ReLU(), nn.Linear(hidden, pose_dim)
        )
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)

    def forward(self, observed: Tensor, future_len: int, action=None, future=None, eta=1.0):
        """(B, T_obs >= C, D) -> (B, future_len, D); `action` is ignored, `future` (B, >=
        future_len, D) is mixed in with weight 1 - eta during training."""
        B = check_forward_inputs(observed, None, self.pose_dim, future_len, future, eta)
        if observed.shape[1] < self.C:
            raise ValueError(f"C={self.C} exceeds the {observed.shape[1]} observed frames")
        mix = mixes(future, eta)
        window = observed[:, -self.C :]
        outs: list[Tensor] = []
        for k in range(future_len):
            y = window[:, -1] + self.mlp(window.flatten(1))
            outs.append(y)
            u = eta * y + (1.0 - eta) * future[:, k] if mix else y
            window = torch.cat([window[:, 1:], u.unsqueeze(1)], dim=1)
        return torch.stack(outs, dim=1) if outs else observed.new_zeros(B, 0, self.pose_dim)
