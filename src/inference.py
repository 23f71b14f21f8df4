"""Deployable predictor: a trained checkpoint in, raw exp-map futures out, no data files needed.

    fc = MotionForecaster.from_checkpoint("outputs/.../checkpoints/last.ckpt")
    future = fc.predict(frames)            # (50, F) or (B, 50, F) at 25 fps -> (..., 25, F)
    future = fc.predict(raw, fps=50)       # (100, F) at 50 fps: every other frame is used
    stream = fc.stream()
    for frame in camera:                   # (F,) each
        future = stream.push(frame)        # None until 50 frames were seen

Frames are raw exp-map rows at the rate the model was trained on, `fc.fps`: 25 fps, every other
row of the dataset's files (protocol §1.3; H3.6M's files are 50 Hz). F is 99 on H3.6M, 117 on
CMU. Frames at a whole multiple of that rate are subsampled with `fps=`; other rates are refused.

Everything the model needs travels in the checkpoint (architecture.md): the network config
(`ckpt["motion"]["config"]`), the weights, and the normaliser buffers (`normalizer.*`), so
normalisation (protocol §2.1) and unnormalisation (§2.2) happen here, in raw F-column space.
"""

from __future__ import annotations

import numbers
import warnings
from collections import deque
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from src.data.normalization import Normalizer
from src.lit.factory import load_trained


class InferenceInputError(ValueError):
    """Frames or an action given to MotionForecaster that it cannot predict from."""


def _check_future_len(future_len: int) -> int:
    # Checked up front: a float or string would otherwise fail deep in the decoding loop, and
    # 0 would make a stream return empty forecasts without a word.
    if not isinstance(future_len, numbers.Integral) or future_len < 1:
        raise InferenceInputError(
            f"future_len must be an integer >= 1 (frames to predict), got {future_len!r}"
        )
    return int(future_len)


def _device(device: str | torch.device) -> torch.device:
    # torch's own errors here are an assertion ("Torch not compiled with CUDA enabled") at the
    # first copy, or a list of every device type for a name like "gpu".
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as err:
        raise InferenceInputError(
            f"device={device!r} is not a torch device; use 'cpu', 'cuda' or 'cuda:N'"
        ) from err
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise InferenceInputError(
            f"device={device!r}, but this torch ({torch.__version__}) sees no CUDA device; "
            "use device='cpu'"
        )
    return dev


class _FixedHorizon(nn.Module):
    """The normalised-space network with a fixed future_len, for export."""

    def __init__(self, net: nn.Module, future_len: int):
        super().__init__()
        self.net, self.future_len = net, future_len

    def forward(self, observed: Tensor, action: Tensor) -> Tensor:
        return self.net(observed, self.future_len, action=action)


# A compiled forecaster compiles each new (batch size, future_len) again, tens of seconds; past
# this many shapes it predicts new ones eagerly (one warning). Below torch's limit of graphs
# per function (torch._dynamo.config.recompile_limit, 8), which with fullgraph was an error.
COMPILED_SHAPES = 4


def compile_for_prediction(net: nn.Module) -> nn.Module:
    """`net` compiled for eval-mode prediction on the device of its weights. On a GPU a
    batch-1 prediction is hundreds of tiny kernels, which mode "reduce-overhead" replays as
    one CUDA graph; on the CPU the default mode, which fuses the small ops (reduce-overhead
    is slower there: benchmarks/benchmark.py times both paths)."""
    cuda = next(net.parameters()).device.type == "cuda"
    # dynamic=False: one static graph per shape, which is what CUDA graphs replay. No
    # fullgraph: networks of one class share torch's graph limit (several forecasters in a
    # process), and past it torch then runs the network eagerly instead of raising.
    mode = "reduce-overhead" if cuda else "default"
    return torch.compile(net, mode=mode, dynamic=False)


class MotionForecaster:
    """A trained predictor in eval mode; inputs and outputs are raw exp-map frames (..., F) at
    `fps` frames per second (25: every other row of the dataset's files, as in training)."""

    def __init__(
        self,
        net: nn.Module,
        normalizer: Normalizer,
        actions: list[str],
        observed_len: int = 50,
        device: str = "cpu",
        compile: bool | str = False,
        fps: float = 25.0,
    ):
        """compile: run the network through `compile_for_prediction` (True, False, or
        "auto": on CUDA only). Off by default: whether it pays has not been measured on a
        GPU, and on the CPU it has not been reliably faster. Each new (batch size,
        future_len) compiles once, tens of seconds; past COMPILED_SHAPES of them new shapes
        run eagerly."""
        if compile not in (True, False, "auto"):
            raise ValueError(f"compile must be true, false or auto, got {compile!r}")
        self.device = _device(device)
        self.net = net.to(self.device).eval()
        self.compiled = compile is True or (compile == "auto" and self.device.type == "cuda")
        self._run = compile_for_prediction(self.net) if self.compiled else self.net
        self._shapes: set[tuple[int, int]] = set()  # compiled (batch size, future_len)
        self._warned = False
        self.normalizer = normalizer.to(self.device).eval()
        self.actions = list(actions)
        self.observed_len = observed_len
        self.num_features = normalizer.num_features
        self.fps = float(fps)

    @classmethod
    def from_checkpoint(
        cls, path: str | Path, device: str = "cpu", compile: bool | str = False
    ) -> MotionForecaster:
        module = load_trained(path)
        observed_len = module.run_info["config"]["data"]["observed_len"]
        # The frame rate of the data it was trained on (MotionDataModule.frame_ms).
        return cls(
            module.net, module.normalizer, module.actions, observed_len, device, compile,
            1000 / module.frame_ms,
        )  # fmt: skip

    def _step(self, fps: float | None) -> int:
        """Every how many input frames one is used: 1 at the model's rate (or fps=None), k for
        k times that rate. A rate that is no whole multiple cannot be subsampled: refused."""
        if fps is None:
            return 1
        if isinstance(fps, bool) or not isinstance(fps, numbers.Real) or not fps > 0:
            raise InferenceInputError(
                f"fps must be a positive number of frames per second, got {fps!r}"
            )
        step = round(fps / self.fps)
        if step < 1 or abs(fps / self.fps - step) > 1e-6:
            raise InferenceInputError(
                f"fps={fps:g}: this model forecasts from frames at {self.fps:g} fps, and {fps:g} "
                f"is not a whole multiple of it. Resample the frames to {self.fps:g} fps (pass "
                f"them without fps=), or pass frames at fps={2 * self.fps:g}, of which every "
                "other one is used (as the protocol downsamples H3.6M's 50 Hz files)."
            )
        return step

    # ------------------------------------------------------------------ checks
    def _action_ids(self, action: str | None, batch: int) -> Tensor:
        if action is None:
            if getattr(self.net, "one_hot", False):
                raise InferenceInputError(
                    "this model takes the action label as input (trained with one-hot); pass "
                    f"action= one of {self.actions}"
                )
            return torch.zeros(batch, dtype=torch.long, device=self.device)
        if action not in self.actions:
            raise InferenceInputError(
                f"unknown action {action!r}; this model knows {self.actions} (or pass None)"
            )
        return torch.full((batch,), self.actions.index(action), device=self.device)

    def _frames(self, frames: np.ndarray | Tensor, shape: str) -> Tensor:
        if isinstance(frames, Tensor):
            # In torch: bfloat16 has no numpy dtype, so numpy cannot convert it.
            frames = frames.detach().to("cpu", torch.float32)
        # Contiguous: torch.as_tensor refuses the negative strides of np.flip or [::-1] views.
        try:
            x = np.asarray(frames, dtype=np.float32, order="C")
        except (TypeError, ValueError) as err:  # ragged lists (a frame of another length), text
            raise InferenceInputError(
                f"frames must be {shape}: a numeric array or tensor of raw exp-map frames, all of "
                f"the same length; numpy could not convert {type(frames).__name__}: {err}"
            ) from err
        if x.shape[-1:] != (self.num_features,):
            raise InferenceInputError(
                f"frames must be {shape} raw exp-map with F={self.num_features} columns "
                f"(the model's dataset), got shape {tuple(x.shape)}"
            )
        # Checked before the copy to the device, where each check would be a host sync.
        if not np.isfinite(x).all():
            bad = np.argwhere(~np.isfinite(x))[0].tolist()
            raise InferenceInputError(
                f"frames contain NaN or inf (first at index {bad}); clean them"
            )
        return torch.as_tensor(x, device=self.device)

    # ------------------------------------------------------------------ prediction
    def _network(self, batch: int, future_len: int) -> nn.Module:
        """The compiled network for a shape it compiled or may still compile, else the eager
        one."""
        shape = (batch, future_len)
        if not self.compiled or shape in self._shapes:
            return self._run
        if len(self._shapes) < COMPILED_SHAPES:
            self._shapes.add(shape)
            return self._run
        if not self._warned:
            self._warned = True
            warnings.warn(
                f"MotionForecaster compiled {COMPILED_SHAPES} (batch size, future_len) shapes, "
                f"{sorted(self._shapes)}; {shape} and any other new shape run eagerly. Predict "
                "with fewer shapes (pad batches), or use compile=False.",
                stacklevel=4,  # the caller of predict or push, under inference_mode
            )
        return self.net

    @torch.inference_mode()
    def predict(
        self,
        frames: np.ndarray,
        action: str | None = None,
        future_len: int = 25,
        fps: float | None = None,
    ) -> np.ndarray:
        """(observed_len, F) or (B, observed_len, F) raw frames at `self.fps` -> (...,
        future_len, F) at `self.fps`. With fps= k times `self.fps`, give k * observed_len
        frames: the newest and every k-th before it are used."""
        step = self._step(fps)
        T, F = self.observed_len * step, self.num_features
        rate = f" at {fps:g} fps" if step > 1 else f" at {self.fps:g} fps"
        x = self._frames(frames, f"({T}, {F}) or (B, {T}, {F}){rate}")
        single = x.dim() == 2
        x = x.unsqueeze(0) if single else x
        if x.dim() != 3 or x.shape[1] != T:
            raise InferenceInputError(
                f"frames must be ({T}, {F}) or (B, {T}, {F}){rate}: the last {T} observed "
                f"frames; got shape {tuple(np.shape(frames))}"
            )
        x = x[:, step - 1 :: step].contiguous()  # the newest frame and every step-th before it
        future_len = _check_future_len(future_len)
        pred = self._network(x.shape[0], future_len)(
            self.normalizer.normalize(x), future_len, action=self._action_ids(action, x.shape[0])
        )
        out = self.normalizer.unnormalize(pred).cpu().numpy()
        return out[0] if single else out

    def stream(
        self, action: str | None = None, future_len: int = 25, fps: float | None = None
    ) -> ForecastStream:
        """Push frames at `self.fps` (or at `fps`, a whole multiple of it: then every k-th
        push, from the first, is used and answered; the others return None)."""
        return ForecastStream(self, action, future_len, self._step(fps))

    # ------------------------------------------------------------------ export
    def _example(self) -> tuple[Tensor, Tensor]:
        observed = torch.zeros(1, self.observed_len, self.normalizer.pose_dim, device=self.device)
        return observed, torch.zeros(1, dtype=torch.long, device=self.device)

    def export_torchscript(self, path: str | Path, future_len: int = 25) -> Path:
        """Trace the normalised-space net: (observed (B, 50, D), action (B,) long) -> (B, T, D).

        Tracing records the decoding loop for this future_len, so the file predicts exactly
        future_len."""
        with torch.inference_mode(False), torch.no_grad():
            traced = torch.jit.trace(
                _FixedHorizon(self.net, future_len).eval(), self._example(), check_trace=False
            )
        traced.save(str(path))
        return Path(path)

    def export_onnx(self, path: str | Path, future_len: int = 25) -> Path:
        """ONNX of the same normalised-space function, batch size dynamic."""
        torch.onnx.export(
            _FixedHorizon(self.net, future_len).eval(),
            self._example(),
            str(path),
            input_names=["observed", "action"],
            output_names=["future"],
            dynamic_axes={"observed": {0: "batch"}, "action": {0: "batch"}, "future": {0: "batch"}},
            dynamo=False,
        )
        return Path(path)


class ForecastStream:
    """Frame-by-frame forecasting over a ring buffer of the last observed_len frames: each push
    predicts from the buffer's window, as `predict` does."""

    def __init__(
        self, forecaster: MotionForecaster, action: str | None, future_len: int, step: int = 1
    ):
        self.fc, self.future_len = forecaster, _check_future_len(future_len)
        self.step, self.pushed = step, 0  # a frame at step times the model's rate: every step-th
        self.action = forecaster._action_ids(action, 1)
        self.buffer: deque[Tensor] = deque(maxlen=forecaster.observed_len)

    @torch.inference_mode()
    def push(self, frame: np.ndarray) -> np.ndarray | None:
        """Add one raw frame (F,); returns (future_len, F) once observed_len frames were seen."""
        F = self.fc.num_features
        x = self.fc._frames(frame, f"({F},)")
        if x.shape != (F,):
            raise InferenceInputError(f"push takes one frame of shape ({F},), got {tuple(x.shape)}")
        self.pushed += 1
        if (self.pushed - 1) % self.step:
            return None
        self.buffer.append(self.fc.normalizer.normalize(x)[None])
        if len(self.buffer) < self.fc.observed_len:
            return None
        window = torch.stack(list(self.buffer), dim=1)  # (1, observed_len, D)
        pred = self.fc._network(1, self.future_len)(window, self.future_len, action=self.action)
        return self.fc.normalizer.unnormalize(pred)[0].cpu().numpy()
