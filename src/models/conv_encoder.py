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
import torch.nn.functional as F
from torch import Tensor, nn
from torch.optim.optimizer import register_optimizer_step_post_hook

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
    in_len: int,
    pose_dim: int,
    nf: int = 16,
    kernel: tuple[int, int] = (2, 7),
    padding: str = "same",
    stride: int = 2,
) -> list[tuple[int, int, int]]:
    """(channels, height, width) after each of the three convolutions.

    Raises ValueError naming `in_len` (time) or `pose_dim` (width) when an input is too
    small for the kernels, which can only happen with VALID padding.
    """
    h, w = in_len, pose_dim
    if h < 1 or w < 1:
        raise ValueError(f"CEM input must be non-empty, got in_len={in_len}, pose_dim={pose_dim}")
    shapes = []
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


# Packed weights are repacked when a weight may have changed: its storage or version counter
# (load_state_dict, in-place ops, .to()), a mode switch, or any optimiser step — the fused
# optimisers update weights in place without bumping their version counters (torch 2.13).
_optimizer_steps = 0


def _count_step(*_) -> None:
    global _optimizer_steps
    _optimizer_steps += 1


register_optimizer_step_post_hook(_count_step)


_ONEDNN = torch.backends.mkldnn.is_available()


def packed_inference(x: Tensor) -> bool:
    """Whether ConvEncoder.conv_act may use oneDNN's packed-weight convolution on x: no
    autograd, float32 on the CPU, a build with oneDNN, not tracing or compiling (export)."""
    return (
        _ONEDNN
        and not torch.is_grad_enabled()
        and x.device.type == "cpu"
        and x.dtype == torch.float32
        and not (torch.jit.is_tracing() or torch.compiler.is_compiling())
    )


class ConvEncoder(nn.Module):
    """CEM: 3 x [TF-padded Conv2d(no bias) -> leaky ReLU 0.2 -> dropout] -> flatten -> Linear.

    Args:
        in_len: number of frames T of the input window (image height).
        pose_dim: pose dimensions D (image width).
        d_out: size of the output code (512 in the paper).
        nf: base filter count; channels are (4nf, 8nf, 8nf) = (64, 128, 128) for nf=16.
        kernel: (time, pose) kernel size, the paper's rectangular 2x7 kernel.
        padding: "same" (H3.6M) or "valid" (CMU), with TensorFlow semantics.
        dropout: drop probabilities after conv1..3; the reference's keep 0.8/0.8/0.5.
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
        if padding not in PADDINGS:
            raise ValueError(f"padding={padding!r} is not supported; use one of {PADDINGS}")
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
        self._packed: dict[int, tuple[tuple, Tensor]] = {}  # see conv_act
        # (pad, conv, act, dropout) of each convolution, grouped once: conv_act runs 75 times
        # per prediction.
        mods = tuple(self.convs)
        self.layers = tuple(mods[i : i + 4] for i in range(0, len(mods), 4))

    def forward(self, x: Tensor) -> Tensor:
        """(B, in_len, pose_dim) -> (B, d_out)."""
        if x.dim() != 3 or tuple(x.shape[1:]) != (self.in_len, self.pose_dim):
            raise ValueError(
                f"ConvEncoder expects (B, {self.in_len}, {self.pose_dim}), got {tuple(x.shape)}"
            )
        h = x.unsqueeze(1)
        # Padding stays a separate F.pad even where TF's is symmetric (conv2 on H3.6M) and the
        # convolution could pad by itself, 6% faster: in torch 2.13 oneDNN then gets the input
        # gradient wrong at 128+ channels (tests/test_models_conv.py, ..._native_convolutions).
        for i, (pad, *_) in enumerate(self.layers):
            h = self.conv_act(i, F.pad(h, pad.padding))
        return self.fc(torch.flatten(h, 1))

    def train(self, mode: bool = True) -> ConvEncoder:
        self._packed = {}
        return super().train(mode)

    def conv_act(self, i: int, x: Tensor) -> Tensor:
        """Convolution i, its leaky ReLU and dropout, on an input already (TF-)padded.

        Without autograd on the CPU (prediction, and the generator's pass that makes the
        discriminator step's fakes) the convolution runs on weights packed once for oneDNN,
        with the activation fused. Why: PyTorch picks its slow convolution for the small inputs
        of batch-1 prediction, or repacks the weights on every call, and a prediction makes 75
        of these calls: 16.7 -> 10 ms at batch 1 on one thread (3% at batch 16). The first
        layer (one input channel) is faster unpacked. Results equal the unpacked path to float
        rounding, and dropout draws the same masks (tests/test_models_conv.py).
        """
        _, conv, act, drop = self.layers[i]
        if i > 0 and packed_inference(x):
            key = (conv.weight.data_ptr(), conv.weight._version, _optimizer_steps)
            if self._packed.get(i, (None,))[0] != key:
                w = torch.ops.mkldnn._reorder_convolution_weight(
                    conv.weight, [0, 0], list(conv.stride), [1, 1], 1, list(x.shape)
                )
                self._packed[i] = (key, w)
            y = torch.ops.mkldnn._convolution_pointwise(
                x, self._packed[i][1], None, [0, 0], list(conv.stride), [1, 1], 1,
                "leaky_relu", [act.negative_slope], "",
            )  # fmt: skip
        else:
            y = act(conv(x))
        return drop(y) if drop.training else y


class IncrementalCEM:
    """Feature-map rows of one ConvEncoder, computed once and reused by later windows.

    Why: the short-term window of eq. (5) slides by one frame per decoding step, and a
    stride-2 convolution row depends only on the rows under its kernel. A row is identified
    by *what it was computed from*: at layer 0 a frame id, at layer l the tuple of the
    layer-(l-1) row ids under its kernel (None where the kernel sees TF zero padding). Two
    rows with the same identity hold the same numbers, so a window only computes the rows
    whose identity is new — the ones touched by the new frame, and the ones near the window
    ends that see padding. This is exact for any kernel, stride and padding (SAME / VALID),
    as long as dropout is off or its masks may be shared (the caller decides that).

    Frame ids are chosen by the caller: ids >= 0 are "stable" frames (observed data that
    keeps its id across calls, e.g. a stream position), ids < 0 are transient (predictions).
    `prune` drops what a later call can no longer reuse, so a long-lived stream stays small.
    """

    def __init__(self, encoder: ConvEncoder):
        self.encoder = encoder
        self.layers = encoder.layers
        n = len(self.layers) + 1
        self.keys: list[dict[tuple, int]] = [{} for _ in range(n)]  # identity -> row id
        self.rows: list[dict[int, Tensor]] = [{} for _ in range(n)]  # row id -> (B, ch, W)
        self.oldest: list[dict[int, int | None]] = [{} for _ in range(n)]  # oldest stable frame
        self._next = [0] * n

    def add_frame(self, frame_id: int, frame: Tensor) -> None:
        """Register frame (B, D) under the caller's id (layer-0 row)."""
        self.rows[0][frame_id] = frame.unsqueeze(1)  # one input channel
        self.oldest[0][frame_id] = frame_id if frame_id >= 0 else None

    def encode(self, frame_ids: list[int]) -> Tensor:
        """The encoder's output (B, d_out) on the window made of these registered frames."""
        enc = self.encoder
        if len(frame_ids) != enc.in_len:
            raise ValueError(f"window has {len(frame_ids)} frames, the encoder {enc.in_len}")
        ids: list[int | None] = list(frame_ids)
        for level, (pad, conv, _, _) in enumerate(self.layers, start=1):
            left, right, top, _ = pad.padding
            (kh, _), (s, _) = conv.kernel_size, conv.stride
            n_in, n_out = len(ids), enc.shapes[level - 1][1]
            keymap, rows, below = self.keys[level], self.rows[level], self.rows[level - 1]
            out_ids = []
            for j in range(n_out):
                key = tuple(
                    ids[r] if 0 <= r < n_in else None for r in range(s * j - top, s * j - top + kh)
                )
                rid = keymap.get(key)
                if rid is None:
                    rid = keymap[key] = self._next[level]
                    self._next[level] += 1
                    olds = [self.oldest[level - 1][i] for i in key if i is not None]
                    stable = all(o is not None for o in olds)
                    self.oldest[level][rid] = min(olds) if stable and olds else None
                out_ids.append(rid)
            # Contiguous runs of rows to compute, each with one conv call.
            missing = [j for j, rid in enumerate(out_ids) if rid not in rows]
            runs: list[list[int]] = []
            for j in missing:
                if runs and runs[-1][-1] == j - 1:
                    runs[-1].append(j)
                else:
                    runs.append([j])
            for run in runs:
                j0, j1 = run[0], run[-1]
                zero = None
                parts = []
                for r in range(s * j0 - top, s * j1 - top + kh):
                    if 0 <= r < n_in:
                        parts.append(below[ids[r]])
                    else:  # TF zero padding of this layer's input
                        if zero is None:
                            ref = below[next(i for i in ids if i is not None)]
                            zero = ref.new_zeros(ref.shape)
                        parts.append(zero)
                x = torch.stack(parts, dim=2)
                if left or right:
                    x = nn.functional.pad(x, (left, right))
                y = enc.conv_act(level - 1, x)
                for j, row in zip(run, y.unbind(2), strict=True):
                    rows[out_ids[j]] = row
            ids = out_ids
        h = torch.stack([self.rows[-1][i] for i in ids], dim=2)
        return enc.fc(torch.flatten(h, 1))

    def prune(self, oldest_frame: int) -> None:
        """Keep only rows built from stable frames >= oldest_frame (the rest cannot recur)."""
        for level in range(len(self.rows)):
            old = self.oldest[level]
            dead = {i for i, o in old.items() if o is None or o < oldest_frame}
            if not dead:
                continue
            for i in dead:
                del old[i]
                self.rows[level].pop(i, None)
            if level:
                self.keys[level] = {k: v for k, v in self.keys[level].items() if v not in dead}
