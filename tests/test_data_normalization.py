"""Normalizer statistics (protocol §2.1) and the unnormalisation identity (§2.2)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from src.data.errors import DataError
from src.data.normalization import Normalizer, wrap_angles
from src.metrics.rotations import expmap_to_rotmat
from tests.conftest import identity_normalizer


def _frames(n: int = 200, seed: int = 0) -> np.ndarray:
    """6 columns: moving, constant, tiny noise (std < 1e-4), moving, constant 0, std ~2e-4."""
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 6), dtype=np.float32)
    x[:, 0] = rng.normal(1.0, 2.0, n)
    x[:, 1] = 0.5
    x[:, 2] = 0.3 + rng.normal(0, 1e-6, n)
    x[:, 3] = rng.uniform(-1, 1, n)
    x[:, 5] = np.where(np.arange(n) % 2 == 0, 2e-4, -2e-4)  # population std exactly 2e-4
    return x


def test_statistics_follow_protocol_rule():
    x = _frames()
    norm = Normalizer.from_sequences([x])
    assert norm.used.tolist() == [True, False, False, True, False, True]
    assert (norm.num_features, norm.pose_dim) == (6, 3)
    assert norm.dim_used.tolist() == [0, 3, 5] and norm.dim_used.dtype == torch.long
    x64 = x.astype(np.float64)
    np.testing.assert_allclose(norm.mean.numpy(), x64.mean(0), rtol=1e-6, atol=1e-7)
    # population std (ddof=0, numpy's default as in the reference), ignored columns -> 1
    expected_std = np.where(norm.used.numpy(), x64.std(0), 1.0)
    np.testing.assert_allclose(norm.std.numpy(), expected_std, rtol=1e-6)
    assert norm.mean.dtype == norm.std.dtype == torch.float32 and norm.used.dtype == torch.bool


def test_threshold_is_inclusive():
    x = np.array([[0.0, 1.0], [2e-4, 1.0]])  # column 0: population std exactly 1e-4
    assert Normalizer.from_sequences([x]).used.tolist() == [True, False]
    assert Normalizer.from_sequences([x], threshold=1.1e-4).used.tolist() == [False, False]


def test_from_sequences_equals_concatenation():
    a, b = _frames(50, 1), _frames(80, 2)
    one = Normalizer.from_sequences([np.concatenate([a, b])])
    two = Normalizer.from_sequences([a, b])
    for name in ("mean", "std", "used"):
        assert torch.equal(getattr(one, name), getattr(two, name)), name


def test_normalize_values_and_leading_dims():
    norm = Normalizer.from_sequences([_frames()])
    x = torch.randn(2, 3, 4, 6)
    z = norm.normalize(x)
    assert z.shape == (2, 3, 4, 3)
    expected = (x - norm.mean) / norm.std
    torch.testing.assert_close(z, expected[..., [0, 3, 5]])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_round_trip_used_columns_and_mean_in_ignored(dtype):
    norm = Normalizer.from_sequences([_frames()])
    x = torch.randn(5, 7, 6, dtype=dtype)
    back = norm.unnormalize(norm.normalize(x))
    assert back.dtype == dtype and back.shape == x.shape
    torch.testing.assert_close(back[..., norm.used], x[..., norm.used])
    ignored = back[..., ~norm.used]
    torch.testing.assert_close(ignored, norm.mean[~norm.used].to(dtype).expand_as(ignored))


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.booleans(), min_size=1, max_size=12).filter(any),
    st.integers(min_value=0, max_value=3),
    st.integers(min_value=0, max_value=2**31 - 1),
)
def test_round_trip_property(used, lead, seed):
    g = torch.Generator().manual_seed(seed)
    f = len(used)
    norm = Normalizer(
        torch.randn(f, generator=g),
        torch.rand(f, generator=g) + 0.1,
        torch.tensor(used),
    )
    x = torch.randn(*([2] * lead), f, generator=g, dtype=torch.float64)
    back = norm.unnormalize(norm.normalize(x))
    mask = torch.tensor(used)
    torch.testing.assert_close(back[..., mask], x[..., mask])
    assert torch.equal(back[..., ~mask], norm.mean[~mask].double().expand_as(back[..., ~mask]))


def test_unnormalize_is_differentiable():
    norm = Normalizer.from_sequences([_frames()])
    z = torch.randn(4, 3, requires_grad=True)
    norm.unnormalize(z).sum().backward()
    torch.testing.assert_close(z.grad, norm.std[norm.used].expand(4, 3))


def test_state_dict_round_trip_through_empty():
    norm = Normalizer.from_sequences([_frames()])
    empty = identity_normalizer(6)
    assert empty.mean.shape == empty.std.shape == empty.used.shape == (6,)
    empty.load_state_dict(norm.state_dict())
    assert empty.pose_dim == 3 and torch.equal(empty.mean, norm.mean)
    assert sorted(norm.state_dict()) == ["mean", "std", "used", "wrap"]


def test_the_wrap_flag_travels_in_the_state_and_a_state_without_it_is_not_wrapped():
    wrapped = Normalizer.from_sequences([_frames()], wrap=True)
    empty = identity_normalizer(6)
    empty.load_state_dict(wrapped.state_dict())
    assert bool(empty.wrap)
    older = {k: v for k, v in wrapped.state_dict().items() if k != "wrap"}  # before the switch
    empty.load_state_dict(older)
    assert not bool(empty.wrap)


# ---- Li et al.'s H3.6M angle wrap (protocol §2.3) ----------------------------------------------


def _triples() -> torch.Tensor:
    """One frame of 3 triples: root translation of norm 10, a joint turned 7 rad, one 1 rad."""
    axis = torch.tensor([[1.0, 2.0, 2.0], [0.0, 0.6, 0.8], [1.0, 0.0, 0.0]])
    axis = axis / axis.norm(dim=-1, keepdim=True)
    return (axis * torch.tensor([[10.0], [7.0], [1.0]], dtype=torch.float64)).flatten()


def test_the_wrap_keeps_every_rotation_and_moves_a_translation_longer_than_2_pi():
    x = _triples()
    y = wrap_angles(x)
    norms = y.view(3, 3).norm(dim=-1)
    torch.testing.assert_close(
        norms, torch.tensor([10 - 2 * torch.pi, 7 - 2 * torch.pi, 1.0]).double()
    )
    # Same direction, and the joint turned 7 rad is the same rotation as turned 7 - 2pi.
    torch.testing.assert_close(y.view(3, 3)[0] / norms[0], x.view(3, 3)[0] / 10)
    torch.testing.assert_close(expmap_to_rotmat(y.view(3, 3)[1]), expmap_to_rotmat(x.view(3, 3)[1]))
    assert torch.equal(y[6:], x[6:])  # below 2pi: unchanged to the bit
    assert torch.equal(wrap_angles(torch.zeros(6)), torch.zeros(6))  # no division by 0


def test_with_the_wrap_the_statistics_and_the_normalised_frames_are_those_of_wrapped_frames():
    rng = np.random.default_rng(0)
    frames = rng.normal(0.0, 4.0, (100, 9))  # many triples longer than 2pi
    wrapped = Normalizer.from_sequences([frames], wrap=True)
    plain_of_wrapped = Normalizer.from_sequences([wrap_angles(torch.from_numpy(frames)).numpy()])
    torch.testing.assert_close(wrapped.mean, plain_of_wrapped.mean)
    torch.testing.assert_close(wrapped.std, plain_of_wrapped.std)
    x = torch.from_numpy(frames[:5])
    torch.testing.assert_close(wrapped.normalize(x), plain_of_wrapped.normalize(wrap_angles(x)))
    assert not torch.allclose(wrapped.mean, Normalizer.from_sequences([frames]).mean)


def test_follows_module_device_and_dtype_moves():
    norm = Normalizer.from_sequences([_frames()]).double()  # float buffers cast, bool kept
    assert norm.used.dtype == torch.bool
    z = norm.normalize(torch.randn(3, 6))  # float32 input on float64 buffers still works
    assert z.dtype == torch.float32
    if torch.cuda.is_available():
        cuda = Normalizer.from_sequences([_frames()]).cuda()
        x = torch.randn(3, 6, device="cuda")
        assert cuda.unnormalize(cuda.normalize(x)).device.type == "cuda"


def test_errors_are_data_errors():
    norm = Normalizer.from_sequences([_frames()])
    with pytest.raises(DataError, match="last dimension of 6"):
        norm.normalize(torch.zeros(2, 5))
    with pytest.raises(DataError, match="last dimension of 3"):
        norm.unnormalize(torch.zeros(2, 6))
    with pytest.raises(DataError, match="at least one training frame"):
        Normalizer.from_sequences([np.zeros((0, 6))])
    with pytest.raises(DataError, match="NaN/inf"):
        Normalizer.from_sequences([np.array([[0.0], [np.nan]])])
