"""Convolutional encoding module (CEM) of Li et al. 2018, protocol §6.2.

A motion window (B, T, D) is read as a one-channel image of height T (time) and width D
(pose dimensions). Three strided convolutions with a rectangular 2x7 kernel grow the
temporal receptive field geometrically (paper §3.1: "two elements of distance n interact
in O(log n) operations"); a linear layer maps the flattened feature map to the code z.

The same module is the long-term encoder (eq. 1, nf=16), the short-term encoder (eq. 2,
nf=16) and the discriminator's encoder (eq. 8, nf=32). The reference is TensorFlow, so
padding follows TF semantics exactly: SAME on H3.6M, VALID on CMU (protocol §6.7).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from src.models.dropout import Dropout

PADDINGS = ("same", "valid")


def tf_conv_geometry(size: int, kernel: int, stride: int, padding: str) -> tuple[int, int, int]:
    """Output length and (before, after) zero padding of one TF conv axis.

    SAME: out = ceil(size / stride), total padding max((out-1)*stride + kernel - size, 0),
    the odd extra row/column goes to the bottom/right (unlike PyTorch's symmetric padding).
    VALID: out = floor((size - kernel) / stride) + 1, no padding; out < 1 means too short.
    """
    if padding == "same":
        out = math.ceil(size / stride)
        total = max((out - 1) * stride + kernel - size, 0)
        return out, total // 2, total - total // 2
    if padding == "valid":
        return (size - kernel) // stride + 1 if size >= kernel else 0, 0, 0
    raise ValueError(f"padding={padding!r} is not supported; use one of {PADDINGS}")


def conv_shapes(
    in_len: int, pose_dim: int, nf=16, kernel=(2, 7), padding="same", stride=2
) -> list[tuple[int, int, int]]:
    """(channels, height, width) after each of the three convolutions; a ValueError names
    `in_len` (time) or `pose_dim` (width) when one is too small for the kernels (VALID only)."""
    if in_len < 1 or pose_dim < 1:
        raise ValueError(f"CEM input must be non-empty, got in_len={in_len}, pose_dim={pose_dim}")
    h, w, shapes = in_len, pose_dim, []
    for i, ch in enumerate((4 * nf, 8 * nf, 8 * nf)):
        h_out = tf_conv_geometry(h, kernel[0], stride, padding)[0]
        w_out = tf_conv_geometry(w, kernel[1], stride, padding)[0]
        for name, value, size, k, out in (
            ("in_len", in_len, h, kernel[0], h_out),
            ("pose_dim", pose_dim, w, kernel[1], w_out),
        ):
            if out < 1:
                raise ValueError(
                    f"CEM input too small: {name}={value} shrinks to {size} before conv{i + 1}, "
                    f"shorter than its kernel {k} under padding={padding!r}; increase {name} "
                    f"or use padding='same'"
                )
        h, w = h_out, w_out
        shapes.append((ch, h, w))
    return shapes


def tf_init_(module: nn.Module) -> None:
    """TF/contrib default initialisation (protocol §6.2): Xavier-uniform weights, zero biases."""
    for m in module.modules():
        if isinstance(m, (nn.Conv2d, nn.Linear)):
            nn.init.xavier_uniform_(m.weight)
            if m.bias is not None:
                nn.init.zeros_(m.bias)


class ConvEncoder(nn.Module):
    """CEM: 3 x [TF-padded Conv2d(no bias) -> leaky ReLU 0.2 -> dropout] -> flatten -> Linear.

    in_len T frames (image height) x pose_dim D (width) -> code of d_out (512); channels
    (4nf, 8nf, 8nf); kernel (time, pose), the paper's 2x7; padding "same" (H3.6M) or "valid"
    (CMU), TF semantics; dropout: drop probabilities after conv1..3 (reference keeps 0.8/0.8/0.5).
    """

    def __init__(
        self,
        in_len: int,
        pose_dim: int,
        d_out: int = 512,
        nf: int = 16,
        kernel: tuple[int, int] = (2, 7),
        padding: str = "same",
        dropout: tuple[float, float, float] = (0.2, 0.2, 0.5),
        stride: int = 2,
    ):
        super().__init__()
        if len(dropout) != 3:
            raise ValueError(f"dropout needs one probability per conv layer (3), got {dropout}")
        self.in_len, self.pose_dim = in_len, pose_dim
        self.shapes = conv_shapes(in_len, pose_dim, nf, tuple(kernel), padding, stride)
        self.flat_dim = math.prod(self.shapes[-1])

        layers: list[nn.Module] = []
        in_ch, h, w = 1, in_len, pose_dim
        for (out_ch, h_out, w_out), p in zip(self.shapes, dropout, strict=True):
            _, top, bottom = tf_conv_geometry(h, kernel[0], stride, padding)
            _, left, right = tf_conv_geometry(w, kernel[1], stride, padding)
            layers += [
                nn.ZeroPad2d((left, right, top, bottom)),  # asymmetric, as TF SAME
                nn.Conv2d(in_ch, out_ch, tuple(kernel), stride=stride, bias=False),
                nn.LeakyReLU(0.2),
                Dropout(p),
            ]
            in_ch, h, w = out_ch, h_out, w_out
        self.convs = nn.Sequential(*layers)
        # Linear code, no activation (protocol §6.2 table, last row).
        self.fc = nn.Linear(self.flat_dim, d_out)
        tf_init_(self)

    def forward(self, x: Tensor) -> Tensor:
        """(B, in_len, pose_dim) -> (B, d_out)."""
        if x.dim() != 3 or tuple(x.shape[1:]) != (self.in_len, self.pose_dim):
            raise ValueError(
                f"ConvEncoder expects (B, {self.in_len}, {self.pose_dim}), got {tuple(x.shape)}"
            )
        # Padding stays a ZeroPad2d layer even where TF's is symmetric (conv2 on H3.6M): with
        # the convolution padding by itself (6% faster), oneDNN in torch 2.13 gets the input
        # gradient wrong at 128+ channels (tests/test_models_conv.py, ..._native_convolutions).
        return self.fc(torch.flatten(self.convs(x.unsqueeze(1)), 1))
