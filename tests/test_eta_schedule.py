import math

import pytest

from src.lit.eta_schedule import Constant, InverseSigmoid, LinearRamp


def test_constant_is_constant_and_checked():
    assert Constant(0.95)(0) == Constant(0.95)(123456) == 0.95
    with pytest.raises(ValueError, match=r"outside \[0, 1\]"):
        Constant(1.5)


def test_linear_ramp_endpoints_and_midpoint():
    ramp = LinearRamp(start=0.0, end=1.0, steps=100)
    assert ramp(0) == 0.0
    assert ramp(50) == pytest.approx(0.5)
    assert ramp(100) == 1.0
    assert ramp(10_000) == 1.0  # stays at the end value
    assert LinearRamp(start=1.0, end=0.2, steps=10)(5) == pytest.approx(0.6)


def test_inverse_sigmoid_matches_formula_and_crosses_half_at_k_ln_k():
    k = 100.0
    sched = InverseSigmoid(k)
    for step in (0, 50, 460, 1000):
        assert sched(step) == pytest.approx(1 - k / (k + math.exp(step / k)))
    assert sched(int(k * math.log(k))) == pytest.approx(0.5, abs=0.01)
    assert sched(10**9) == 1.0
    assert sched(0) < 0.01
