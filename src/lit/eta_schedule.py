"""Schedules of eta, Li et al. eq. (10): the weight of the model's own prediction in the frames
fed back to the decoder in training (1: Martinez's "sampling-based loss"; 0: teacher forcing;
evaluation: 1). A pure function of the iteration, so a resume continues it exactly."""

from __future__ import annotations

import math


def _check_unit(name: str, value: float) -> float:
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"sampling.{name}={value} is outside [0, 1]; eta is a mixing weight.")
    return float(value)


class Constant:
    """eta fixed for the whole run. The reference code of Li et al. uses 0.95 (protocol §6.4)."""

    def __init__(self, eta: float = 0.95):
        self.value = _check_unit("eta", eta)

    def __call__(self, step: int) -> float:
        return self.value


class LinearRamp:
    """eta moves linearly from `start` to `end` over `steps` iterations, then stays."""

    def __init__(self, start: float = 0.0, end: float = 1.0, steps: int = 20000):
        self.start, self.end = _check_unit("start", start), _check_unit("end", end)
        if steps <= 0:
            raise ValueError(f"sampling.steps={steps} must be a positive number of steps.")
        self.steps = int(steps)

    def __call__(self, step: int) -> float:
        return self.start + min(max(step, 0) / self.steps, 1.0) * (self.end - self.start)


class InverseSigmoid:
    """Scheduled sampling (Bengio et al. 2015): the teacher-forcing probability decays as
    k / (k + exp(step / k)), so eta rises from about 0 to 1, crossing 0.5 at step k * ln(k)."""

    def __init__(self, k: float = 1000.0):
        if k < 1.0:
            raise ValueError(f"sampling.k={k} must be >= 1 (the decay would start above 1).")
        self.k = float(k)

    def __call__(self, step: int) -> float:
        x = max(step, 0) / self.k
        return 1.0 if x > 700 else 1.0 - self.k / (self.k + math.exp(x))  # exp overflows past 700
