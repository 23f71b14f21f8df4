"""Dropout drawn the way TensorFlow draws it: one uniform number per element against a threshold.

Why not nn.Dropout on the CPU: its bernoulli_ draws one element at a time (about 9 ns per
element here), rand is vectorised (about 3 ns); the CEMs drop about 36 million activations per
conv_s2s + adversarial iteration, and the step is about 1.1x faster (`benchmarks/dropout.py`).
The masks have the same distribution (keep with probability 1 - p, to float32 resolution), the
reference's own (tf.nn.dropout, protocol §6.2: keep where floor(keep_prob + u) = 1), and come
from the same generator, so seeding and checkpointed random states work as before (a seed draws
other masks than nn.Dropout would). On other devices nn.Dropout's fused kernel is faster.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class Dropout(nn.Dropout):
    def forward(self, x: Tensor) -> Tensor:
        if not self.training or x.device.type != "cpu" or not 0 < self.p < 1:
            return super().forward(x)
        return self.drop_uniform(x)

    def drop_uniform(self, x: Tensor) -> Tensor:
        """The CPU path, on any device. On CUDA a compiled graph draws eager's masks only this
        way: inductor lowers nn.Dropout to uniform draws, not to eager's fused kernel
        (tests/test_compile.py uses it to compare the two steps there)."""
        keep = 1.0 - self.p
        # Drawn in float32 whatever x's dtype: bfloat16 has 8 bits of mantissa, and its uniform
        # numbers keep about 0.001 too many elements (p=0.5 keeps 0.501 under bf16-mixed).
        # In place: one buffer, no bool copy. rand, not rand_like: the mask is drawn in logical
        # order whatever x's memory layout.
        mask = torch.rand(x.shape, dtype=torch.float32, device=x.device).lt_(keep)
        return x * mask.to(x.dtype).div_(keep)
