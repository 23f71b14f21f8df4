"""History Repeats Itself (Mao, Liu, Salzmann, ECCV 2020), the angle / exp-map variant.

Specification: shared docs/hisrep.md (facts and shapes of the authors' released code);
"§n" below is a section of it. One step predicts T = 10 frames from the sequence x seen so far:

    k_i = f_k(x_{i..i+M-1}),  i = 0..S-L         keys: sub-sequences ending T before the end
    q   = f_q(x_{S-M..S-1})                       query: the last M frames
    a_i = (q k_i + ε) / Σ_j (q k_j + ε)           §3: sum-normalised, not softmax
    U   = Σ_i a_i D x_{i..i+L-1}                  values: DCT of the L = M+T frame windows
    P   = [x_{S-M}, ..., x_{S-1}, x_{S-1} × T]    §2: the last M frames, the last one repeated
    Y   = GCN([D P, U]) (features 0..dct_n-1)     §4: nodes are the K dims, GCN(z) = z + ...
    out = Dᵀ Y                                    L frames: M reconstructed, then T predicted

Longer horizons roll out (§5): the T predicted frames are appended to x and the step repeats, so
the keys and values grow by T each step and the query is the predicted frames. Training (§6) is
single-step: `objective` is the authors' L1 loss on the L frames `step` returns.

Inputs are the K = 48 used exp-map dims in radians, not normalised (§1): the authors train on
raw angles, and the scale of ε against q·k below was set for them.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from src.models.conv_s2s import check_forward_inputs, mixes
from src.models.dropout import Dropout


def dct_matrix(L: int) -> Tensor:
    """Orthonormal DCT-II basis (§2), float64: D[k, i] = w_k cos(π (i + ½) k / L), w_0 = √(1/L),
    w_k = √(2/L). D x is the spectrum of L frames x (L, ...); Dᵀ = D⁻¹ inverts it."""
    k = torch.arange(L, dtype=torch.float64).unsqueeze(1)
    i = torch.arange(L, dtype=torch.float64).unsqueeze(0)
    w = torch.full((L, 1), math.sqrt(2.0 / L), dtype=torch.float64)
    w[0] = math.sqrt(1.0 / L)
    return w * torch.cos(math.pi * (i + 0.5) * k / L)


class GraphConv(nn.Module):
    """out = A (X W) + b on X (B, nodes, F_in) (§4): A a learnable dense adjacency, W shared by
    all nodes. W, A and b all drawn from U(-1/√F_out, 1/√F_out), as the authors do (§4)."""

    def __init__(self, f_in: int, f_out: int, nodes: int):
        super().__init__()
        self.W = nn.Parameter(torch.empty(f_in, f_out))
        self.A = nn.Parameter(torch.empty(nodes, nodes))
        self.b = nn.Parameter(torch.empty(f_out))
        bound = 1.0 / math.sqrt(f_out)
        for p in (self.W, self.A, self.b):
            nn.init.uniform_(p, -bound, bound)

    def forward(self, X: Tensor) -> Tensor:
        return self.A @ (X @ self.W) + self.b


class GCLayer(nn.Module):
    """GC -> BatchNorm -> tanh -> dropout. The BN runs on the tensor flattened to (B, nodes·F):
    every (node, feature) pair has its own statistics (§4, §9 trap 11)."""

    def __init__(self, f_in: int, f_out: int, nodes: int, dropout: float):
        super().__init__()
        self.gc = GraphConv(f_in, f_out, nodes)
        self.bn = nn.BatchNorm1d(nodes * f_out)
        self.drop = Dropout(dropout)

    def forward(self, X: Tensor) -> Tensor:
        y = self.gc(X)
        return self.drop(torch.tanh(self.bn(y.flatten(1)).view_as(y)))


class GCBlock(nn.Module):
    """Two GC layers plus the block's input (§4, step 2)."""

    def __init__(self, f: int, nodes: int, dropout: float):
        super().__init__()
        self.layers = nn.Sequential(GCLayer(f, f, nodes, dropout), GCLayer(f, f, nodes, dropout))

    def forward(self, X: Tensor) -> Tensor:
        return X + self.layers(X)


class HisRep(nn.Module):
    """Args, defaults the published configuration (§0): pose_dim K (48 used exp-map dims);
    num_actions unused (no action label); N observed frames (50); M query/key length (10, the
    convs' receptive field); T frames per step (10); dct_n DCT coefficients kept of L = M+T (20:
    all); d_model attention and GCN width (256); num_stage residual GC blocks (12); dropout
    (0.3, hard-coded by the authors, §9 trap 3)."""

    def __init__(
        self,
        pose_dim: int = 48,
        num_actions: int | None = None,
        N: int = 50,
        M: int = 10,
        T: int = 10,
        dct_n: int = 20,
        d_model: int = 256,
        num_stage: int = 12,
        dropout: float = 0.3,
    ):
        super().__init__()
        if M != 10:
            raise ValueError(f"M={M}: the key/query convs (kernels 6 and 5) see exactly 10 frames")
        if T < 1 or N < M + T:
            raise ValueError(f"need T >= 1 and N >= M + T (one sub-sequence): N={N} T={T}")
        if not 1 <= dct_n <= M + T:
            raise ValueError(f"dct_n={dct_n} must lie in [1, L = M + T = {M + T}]")
        self.pose_dim, self.num_actions = pose_dim, num_actions
        self.K, self.N, self.M, self.T, self.L, self.dct_n = pose_dim, N, M, T, M + T, dct_n
        K = pose_dim

        # §3: f_k and f_q, same structure, separate weights; no bias (see `attend` for why that
        # matters), no padding: one output per M = 10 frames.
        def conv_branch():
            return nn.Sequential(
                nn.Conv1d(K, d_model, kernel_size=6, bias=False),
                nn.ReLU(),
                nn.Conv1d(d_model, d_model, kernel_size=5, bias=False),
                nn.ReLU(),
            )

        self.f_k, self.f_q = conv_branch(), conv_branch()

        # §4: the GCN on K nodes, each with the dct_n coefficients of P and dct_n of U.
        self.gc1 = GCLayer(2 * dct_n, d_model, K, dropout)
        self.blocks = nn.Sequential(*(GCBlock(d_model, K, dropout) for _ in range(num_stage)))
        self.gc7 = GraphConv(d_model, 2 * dct_n, K)

        # §2: the first dct_n rows of D (all 20 by default). A buffer, so it follows .to(); not
        # saved in checkpoints, as it is a function of L and dct_n, not learnt state.
        D = dct_matrix(self.L)[:dct_n].to(torch.get_default_dtype())
        self.register_buffer("D", D, persistent=False)

    def attend(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Motion attention (§3) over x (B, S >= N, K): U (B, K, dct_n) and the weights a
        (B, S-L+1), one per sub-sequence i (key: frames i..i+M-1, value: frames i..i+L-1).
        Computed from x as it stands: for the rollout's extended x this gives the keys and
        values the authors append step by step (§5), as the convs have no padding."""
        S, M, T = x.shape[1], self.M, self.T
        xt = x.transpose(1, 2)  # (B, K, S): Conv1d runs over time
        # The authors divide by 1000 (a leftover of their millimetre code, §3). The convs have
        # no bias and ReLU is positively homogeneous, so q and k shrink by 1e-3 each and the
        # sum-normalisation cancels it: only ε's weight relative to q·k changes. Kept for that.
        k = self.f_k(xt[:, :, : S - T] / 1000.0)  # (B, d, S-L+1): keys end T before the end
        q = self.f_q(xt[:, :, S - M :] / 1000.0)  # (B, d, 1)
        s = (q.transpose(1, 2) @ k).squeeze(1) + 1e-15  # q·k_i >= 0 after the ReLUs
        # Sum-normalised, not softmax (the paper, unchecked in §3: softmax has vanishing
        # gradients), and no √d scaling.
        a = s / s.sum(dim=1, keepdim=True)
        V = x.unfold(1, self.L, 1) @ self.D.T  # (B, S-L+1, K, dct_n): DCT of each window
        U = torch.einsum("bi,bikc->bkc", a, V)  # a convex combination of the value spectra
        return U, a

    def step(self, x: Tensor) -> Tensor:
        """One step (§2-4) on x (B, S >= N, K): (B, L, K), frames S-M..S-1 reconstructed and
        then the T predicted frames S..S+T-1. The authors' L1 loss is taken on all L (§6)."""
        U, _ = self.attend(x)
        # P: the last M frames, then T copies of the last (the padded input, §2).
        P = torch.cat([x[:, -self.M :], x[:, -1:].expand(-1, self.T, -1)], dim=1)
        z = torch.cat([(self.D @ P).transpose(1, 2), U], dim=2)  # (B, K, 2·dct_n)
        # §4: residual over the whole GCN, so with gc7 at zero the step returns P itself.
        y = z + self.gc7(self.blocks(self.gc1(z)))
        return self.D.T @ y[:, :, : self.dct_n].transpose(1, 2)  # inverse DCT: (B, L, K)

    def objective(self, observed: Tensor, future: Tensor) -> Tensor:
        """The authors' training loss (§6): one step from the N observed frames, L1 over its L
        frames (the M reconstructed observed ones, then the first T of `future`), summed over
        the K dims and averaged over batch and frames (the paper averages over dims too: 48x
        smaller, which Adam all but ignores)."""
        if future.shape[1] < self.T:
            raise ValueError(
                f"the objective needs T={self.T} future frames, got {future.shape[1]}: set "
                f"data.train_future_len >= {self.T}"
            )
        target = torch.cat([observed[:, -self.M :], future[:, : self.T]], dim=1)
        return (self.step(observed) - target).abs().sum(dim=-1).mean()

    def forward(self, observed: Tensor, future_len: int, action=None, future=None, eta=1.0):
        """(B, N, K) -> (B, future_len, K) by ceil(future_len / T) steps (§5). `action` is
        ignored. The authors never roll out in training (§5); should the project, `future`
        (B, >= future_len, K) is mixed into the appended frames with weight 1 - eta, as the
        fed-back frames of Li et al.'s eq. (10); eta = 1 (evaluation) is the authors' rollout."""
        B = check_forward_inputs(observed, self.N, self.K, future_len, future, eta)
        mix = mixes(future, eta)
        steps = -(-future_len // self.T)
        x, preds = observed, []
        for j in range(steps):
            pred = self.step(x)[:, self.M :]  # (B, T, K)
            preds.append(pred)
            if j == steps - 1:
                break  # the authors also extend x after the last step, never to read it (§5)
            if mix:
                pred = eta * pred + (1.0 - eta) * future[:, j * self.T : (j + 1) * self.T]
            x = torch.cat([x, pred], dim=1)
        if not preds:
            return observed.new_zeros(B, 0, self.K)
        return torch.cat(preds, dim=1)[:, :future_len]
