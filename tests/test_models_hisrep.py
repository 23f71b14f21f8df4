"""HisRep (Mao et al. ECCV 2020, spec: shared docs/hisrep.md): parameter count of the published
configuration, DCT basis, motion attention, the GCN's residual, the 3-step rollout against the
spec's incremental keys and values, batch independence."""

import pytest
import torch

from src.models import HisRep
from src.models.hisrep import dct_matrix

K, N, M, T, L = 48, 50, 10, 10, 20


def small(**kw) -> HisRep:
    """The published shapes (K, N, M, T, dct_n) with a narrow, shallow GCN: fast on 1 thread."""
    torch.manual_seed(0)
    return HisRep(pose_dim=K, num_actions=15, d_model=32, num_stage=2, **kw)


def observed(B: int = 3, S: int = N, seed: int = 1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return 0.5 * torch.randn(B, S, K, generator=g)  # radians, as the raw exp-map dims


def n_params(module) -> int:
    return sum(p.numel() for p in module.parameters())


def test_published_configuration_has_3_076_904_parameters():
    model = HisRep(pose_dim=48, num_actions=15)  # the project passes both; defaults = §0
    assert n_params(model) == 3_076_904  # §6, printed as 3.08M by the authors
    assert n_params(model.f_k) == n_params(model.f_q) == 401_408
    gcn = [model.gc1, model.blocks, model.gc7]
    assert sum(map(n_params, gcn)) == 2_274_088
    assert [n_params(model.gc1.gc), n_params(model.gc1.bn), n_params(model.gc7)] == [
        12_800,
        24_576,
        12_584,
    ]
    assert len(model.blocks) == 12 and n_params(model.blocks[0]) == 185_344
    assert model.gc1.drop.p == 0.3 and model.D.shape == (20, 20)


def test_graph_conv_init_is_uniform_over_one_over_sqrt_f_out():
    torch.manual_seed(0)
    gc = HisRep().gc1.gc  # 40 -> 256: bound 1/16 for W, A and b alike
    for p in (gc.W, gc.A, gc.b):
        assert 0.055 < p.abs().max() <= 1 / 16


@pytest.mark.parametrize("future_len", [0, 1, 10, 25, 30])
def test_output_shapes(future_len):
    model = small()
    x = observed()
    assert model(x, future_len).shape == (3, future_len, K)
    assert model.step(x).shape == (3, L, K)  # M reconstructed + T predicted frames (§6)


def test_wrong_inputs_are_refused():
    model = small()
    with pytest.raises(ValueError, match="observed must be"):
        model(observed(S=49), 10)
    with pytest.raises(ValueError, match="M=5"):
        HisRep(M=5)
    with pytest.raises(ValueError, match="dct_n"):
        HisRep(dct_n=21)


def test_dct_basis_is_orthonormal_dct_ii():
    scipy_fft = pytest.importorskip("scipy.fft")
    D = dct_matrix(L)
    I = torch.eye(L, dtype=torch.float64)
    torch.testing.assert_close(D.T @ D, I, rtol=0, atol=1e-12)
    torch.testing.assert_close(D @ D.T, I, rtol=0, atol=1e-12)
    x = torch.randn(L, K, dtype=torch.float64)
    ref = torch.from_numpy(scipy_fft.dct(x.numpy(), type=2, norm="ortho", axis=0))
    torch.testing.assert_close(D @ x, ref, rtol=0, atol=1e-12)
    # the model's float32 buffer: inverse(D x) = Dᵀ D x = x
    Dm = small().D
    xf = x.float()
    torch.testing.assert_close(Dm.T @ (Dm @ xf), xf, rtol=0, atol=1e-5)


def test_attention_weights_are_sum_normalised_scores_and_the_1000_cancels():
    model = small()
    x = observed(S=60)
    U, a = model.attend(x)
    assert a.shape == (3, 60 - L + 1) and U.shape == (3, K, 20)
    assert (a >= 0).all()
    torch.testing.assert_close(a.sum(1), torch.ones(3))
    # a_i = q·k_i / Σ_j q·k_j with q, k from the unscaled frames: the ÷1000 cancels (§3).
    xt = x.transpose(1, 2)
    k = model.f_k(xt[:, :, : 60 - T])
    q = model.f_q(xt[:, :, -M:])
    s = torch.einsum("bd,bdi->bi", q[:, :, 0], k)
    torch.testing.assert_close(a, s / s.sum(1, keepdim=True))
    assert not torch.allclose(a, s.softmax(1), atol=1e-3)  # not softmax


def incremental_attention(model, x_obs, appended):
    """The spec's §5 literally: keys from the first N-T frames and values of the first N, then,
    after each appended chunk (new length S), 10 keys from frames S-29..S-11 and 10 value windows
    starting at S-29..S-20; the query is the last 10 frames."""

    def keys(frames):
        return model.f_k(frames.transpose(1, 2) / 1000)

    def values(x, starts):
        return torch.stack([model.D @ x[:, i : i + L] for i in starts], dim=1)  # (B, n, c, K)

    k, V, x = keys(x_obs[:, : N - T]), values(x_obs, range(N - L + 1)), x_obs
    for chunk in appended:
        x = torch.cat([x, chunk], dim=1)
        S = x.shape[1]
        k = torch.cat([k, keys(x[:, S - 29 : S - 10])], dim=2)
        V = torch.cat([V, values(x, range(S - 29, S - 19))], dim=1)
    q = model.f_q(x[:, -M:].transpose(1, 2) / 1000)
    s = torch.einsum("bd,bdi->bi", q[:, :, 0], k) + 1e-15
    a = s / s.sum(1, keepdim=True)
    return torch.einsum("bi,bick->bkc", a, V), a


def test_attention_on_the_extended_sequence_equals_the_incremental_keys_and_values():
    model = small()
    x = observed()
    chunks = [observed(seed=2)[:, :T], observed(seed=3)[:, :T]]
    for j in range(3):  # steps 1, 2, 3: 31, 41, 51 sub-sequences
        U, a = model.attend(torch.cat([x, *chunks[:j]], dim=1))
        U_ref, a_ref = incremental_attention(model, x, chunks[:j])
        assert a.shape[1] == 31 + 10 * j
        torch.testing.assert_close(a, a_ref)
        torch.testing.assert_close(U, U_ref)


def test_zero_last_layer_makes_the_gcn_the_identity_and_the_model_zero_velocity():
    model = small()  # in training mode: dropout and the BN's batch statistics do not leak
    torch.nn.init.zeros_(model.gc7.W)
    torch.nn.init.zeros_(model.gc7.b)
    x = observed()
    padded = torch.cat([x[:, -M:], x[:, -1:].expand(-1, T, -1)], dim=1)  # §2's P
    torch.testing.assert_close(model.step(x), padded, rtol=0, atol=1e-5)
    torch.testing.assert_close(model(x, 25), x[:, -1:].expand(-1, 25, -1), rtol=0, atol=1e-5)


def test_each_gc_block_adds_its_input():
    # With a block's second GC layer at zero, BN(0) = 0 (eval: running mean 0, var 1), tanh(0)
    # = 0, and the block is the identity: the model equals one without the blocks.
    model = small().eval()
    x = observed()
    for block in model.blocks:
        torch.nn.init.zeros_(block.layers[1].gc.W)
        torch.nn.init.zeros_(block.layers[1].gc.b)
    with torch.no_grad():
        out = model.step(x)
        model.blocks = torch.nn.Sequential()  # num_stage = 0
        torch.testing.assert_close(model.step(x), out)


def test_rollout_feeds_the_predictions_back_in_ceil_steps():
    model = small().eval()
    x = observed()
    calls = []
    step = model.step
    model.step = lambda seq: calls.append(seq.shape[1]) or step(seq)
    with torch.no_grad():
        out = model(x, 25)
        assert calls == [50, 60, 70]  # 25 frames: 3 steps of 10, on the extended sequence
        torch.testing.assert_close(out[:, :10], model(x, 10), rtol=0, atol=0)
        torch.testing.assert_close(out[:, 10:20], step(torch.cat([x, out[:, :10]], 1))[:, M:])
        torch.testing.assert_close(out[:, 20:], step(torch.cat([x, out[:, :20]], 1))[:, M:15])


def test_eta_mixes_the_ground_truth_into_the_appended_frames():
    model = small().eval()
    x, future = observed(), observed(seed=4)[:, :25]
    with torch.no_grad():
        torch.testing.assert_close(model(x, 25, future=future, eta=1.0), model(x, 25))
        out = model(x, 25, future=future, eta=0.0)  # teacher forcing: the next step sees GT
        torch.testing.assert_close(out[:, :10], model(x, 10))
        torch.testing.assert_close(
            out[:, 10:20], model.step(torch.cat([x, future[:, :10]], 1))[:, M:]
        )


def test_batch_independence_in_eval_mode():
    model = small().eval()
    x = observed(B=4)
    with torch.no_grad():
        batch = model(x, 25)
        for i in range(4):
            torch.testing.assert_close(model(x[i : i + 1], 25), batch[i : i + 1])


def test_every_parameter_gets_a_gradient_from_the_one_step_l1_loss():
    model = small()
    window = observed(S=N + T)  # a 60-frame training window: the loss is on its last 20 (§6)
    loss = (model.step(window[:, :N]) - window[:, N - M :]).abs().sum(2).mean()
    loss.backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.any()]
    assert not missing, missing


def test_objective_is_the_authors_l1_over_the_last_20_frames_summed_over_dims():
    """With gc7 at zero the step returns P (the last 10 observed frames, then the last one 10
    times): the first 10 frames cost nothing, each future frame sum_k |x_{N-1,k} - y_{t,k}|."""
    model = small()
    torch.nn.init.zeros_(model.gc7.W)
    torch.nn.init.zeros_(model.gc7.b)
    x, y = observed(), observed(seed=2)[:, :25]  # a 25-frame future: only the first T count
    want = (x[:, -1:] - y[:, :T]).abs().sum(dim=2).sum(dim=1).mean() / L
    torch.testing.assert_close(model.objective(x, y), want, rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="train_future_len"):
        model.objective(x, y[:, : T - 1])
