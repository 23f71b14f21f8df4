"""Incremental short-term encoding (IncrementalCEM) gives the numbers of re-encoding each window.

Small widths (nf=4, d_z=32) keep this fast; the row structure depends only on C, kernel,
padding and the stride, which are the real ones."""

from __future__ import annotations

import pytest
import torch

from src.models.conv_encoder import IncrementalCEM
from src.models.conv_s2s import ConvSeq2Seq

# Every (padding, C, kernel) the paper uses or ablates that builds; VALID (CMU, D = 70) needs
# longer windows for the taller kernels.
CASES = [("same", C, k) for C in (5, 10, 20) for k in ((2, 7), (4, 4), (7, 2))] + [
    ("valid", 10, (2, 7)),
    ("valid", 20, (2, 7)),
    ("valid", 40, (4, 4)),
    ("valid", 50, (7, 2)),
]


def pair(padding="same", C=20, kernel=(2, 7), **kw):
    """(incremental, recomputing) models with identical weights."""
    torch.manual_seed(0)
    kw = {"nf": 4, "d_z": 32, "d_dec": 32, **kw}
    D = 54 if padding == "same" else 70
    inc = ConvSeq2Seq(D, 15, C=C, kernel=kernel, padding=padding, **kw)
    ref = ConvSeq2Seq(D, 15, C=C, kernel=kernel, padding=padding, incremental=False, **kw)
    ref.load_state_dict(inc.state_dict())
    return inc, ref, D


@pytest.mark.parametrize("padding, C, kernel", CASES)
def test_eval_outputs_equal_recomputation(padding, C, kernel):
    eta, offset = (0.6, True) if C == 10 else (1.0, False) if C == 5 else (0.6, False)
    inc, ref, D = pair(padding, C, kernel, reference_eta_offset=offset)
    inc.eval(), ref.eval()
    assert inc.uses_incremental() and not ref.uses_incremental()
    observed, future = torch.randn(3, 50, D), torch.randn(3, 25, D)
    out = inc(observed, 25, future=future, eta=eta)
    torch.testing.assert_close(out, ref(observed, 25, future=future, eta=eta), rtol=1e-5, atol=1e-5)


def test_only_new_rows_are_computed():
    # C = 20, 2x7 SAME, 25 windows starting at frames 30..54. Hand count of distinct rows:
    # conv1 row i of window s reads frames s+2i..: starts 30..(54+18) -> 43 rows (of 250);
    # conv2 (10 -> 5, no padding) starts s+4j -> 30..(54+16) -> 41 rows (of 125);
    # conv3 (5 -> 3, one bottom padding row): rows 0, 1 start s+8j -> 33, plus row 2, which
    # sees padding, once per window -> 25: 58 rows (of 75). Frames: 50 observed + 24 appended.
    inc, _, _ = pair()
    assert inc.short_encoder.shapes == [(16, 10, 27), (32, 5, 14), (32, 3, 7)]
    cem = IncrementalCEM(inc.short_encoder)
    seen = []
    orig = cem.encode
    cem.encode = lambda ids: (seen.append(ids), orig(ids))[1]
    inc.eval().decode_incremental(torch.randn(1, 50, 54), 25, cache=(None, cem))
    assert len(seen) == 25
    assert [len(r) for r in cem.rows] == [74, 43, 41, 58]


@pytest.mark.parametrize(
    "padding, C, kernel", [("same", 20, (2, 7)), ("same", 10, (4, 4)), ("valid", 20, (2, 7))]
)
def test_training_gradients_equal_recomputation(padding, C, kernel):
    # Without dropout the incremental path runs in training too; eq. (10) mixing on, and every
    # parameter's gradient (through the kept rows) must match.
    inc, ref, D = pair(padding, C, kernel, dropout=(0.0, 0.0, 0.0), decoder_dropout=0.0)
    inc.train(), ref.train()
    assert inc.uses_incremental()
    observed, future = torch.randn(4, 50, D), torch.randn(4, 25, D)
    for m in (inc, ref):
        loss = (m(observed, 25, future=future, eta=0.7) - future).pow(2).mean()
        loss.backward()
    for (name, a), (_, b) in zip(inc.named_parameters(), ref.named_parameters(), strict=True):
        assert a.grad is not None and a.grad.abs().sum() > 0, name
        torch.testing.assert_close(a.grad, b.grad, rtol=1e-4, atol=1e-6, msg=name)


def test_training_with_dropout_falls_back_to_recomputation():
    # Recomputing draws a fresh dropout mask per window; kept rows cannot, so the default
    # (exact) setting recomputes: same random numbers, bit-identical output.
    inc, ref, _ = pair()
    inc.train(), ref.train()
    assert not inc.uses_incremental()
    observed, future = torch.randn(2, 50, 54), torch.randn(2, 25, 54)
    torch.manual_seed(1)
    a = inc(observed, 25, future=future, eta=0.9)
    torch.manual_seed(1)
    b = ref(observed, 25, future=future, eta=0.9)
    torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_shared_dropout_masks_run_incrementally_and_train():
    inc, _, _ = pair(share_dropout_masks=True)
    inc.train()
    assert inc.uses_incremental()
    observed, future = torch.randn(2, 50, 54), torch.randn(2, 25, 54)
    torch.manual_seed(1)
    a = inc(observed, 25, future=future, eta=0.9)
    a.pow(2).mean().backward()
    for name, p in inc.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
    # ...and in eval mode (dropout off) it is the exact path again
    inc.eval()
    _, ref, _ = pair()
    ref.load_state_dict(inc.state_dict())
    torch.testing.assert_close(inc(observed, 25), ref.eval()(observed, 25), rtol=1e-5, atol=1e-5)


def test_state_dict_keys_unchanged_and_checkpoints_load():
    inc, ref, _ = pair()
    assert list(inc.state_dict()) == list(ref.state_dict())
    torch.manual_seed(5)
    old = ConvSeq2Seq(54, 15, incremental=False).eval()
    new = ConvSeq2Seq(54, 15, incremental=True).eval()
    new.load_state_dict(old.state_dict())  # strict: a key change would raise
    x = torch.randn(2, 50, 54)
    torch.testing.assert_close(new(x, 25), old(x, 25), rtol=1e-5, atol=1e-5)


def test_stream_cache_reuses_rows_across_calls_and_stays_bounded():
    # A stream: frame t arrives, predict from frames t-49..t. The cache carries rows across
    # calls (stable ids = stream positions) and must give the fresh-call numbers.
    inc, ref, _ = pair()
    inc.eval(), ref.eval()
    frames = torch.randn(1, 70, 54)
    cache = inc.new_cache()
    sizes = []
    for start in range(21):
        window = frames[:, start : start + 50]
        out = inc.decode_incremental(window, 25, cache=cache, first_id=start)
        torch.testing.assert_close(out, ref(window, 25), rtol=1e-5, atol=1e-5)
        for cem in cache:
            cem.prune(start + 1)
        sizes.append(sum(len(r) for r in cache[1].rows))
    # Pruned to rows built from frames still in the next window: the size stops growing.
    assert max(sizes[10:]) == max(sizes[15:])
    assert all(i >= start + 1 for i in cache[1].rows[0])


def test_forward_reuses_rows_on_the_cpu_only(monkeypatch):
    inc, ref, D = pair()
    inc.eval(), ref.eval()
    calls = []
    original = inc.decode_incremental
    monkeypatch.setattr(
        inc, "decode_incremental", lambda *a, **k: calls.append(1) or original(*a, **k)
    )
    inc(torch.randn(2, 50, D), 5)
    assert calls == [1]
    if torch.cuda.is_available():  # on a GPU, recomputing was faster (docs/performance.md)
        inc.cuda()
        inc(torch.randn(2, 50, D, device="cuda"), 5)
        assert calls == [1]
