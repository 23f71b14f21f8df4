"""MotionForecaster: a checkpoint in, raw exp-map futures out, no data files needed (README,
"Using a trained predictor"). Frames (F: 99 on H3.6M, 117 on CMU) are at the model's `fps`, 25:
every other row of the files (protocol §1.3); (un)normalisation (§2.1, §2.2) is done here."""

from __future__ import annotations

import numbers
import warnings
from collections import deque
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from src.build import load_trained
from src.data.normalization import Normalizer
from src.lit.parts import compiled

# A frame is 3 root-position columns (any size) then one exp-map triple per joint, whose norm is
# the joint's rotation angle. In radians real motion stays within pi (every frame of the H3.6M
# and CMU archives: at most 3.1416); in degrees every one of their frames has a joint beyond 21.
# Beyond 2 pi (the same rotation as a smaller one) is degrees, not motion.
MAX_RADIANS = 2 * np.pi


def largest_rotation(frames: np.ndarray, used) -> tuple[float, tuple[int, ...]]:
    """The largest joint rotation angle of raw frames (..., F) and where: (..., joint). `used`
    (F bools, a Normalizer's): only joints with a used column count, as only they are scored."""
    angles = np.linalg.norm(frames[..., 3:].reshape(*frames.shape[:-1], -1, 3), axis=-1)
    angles = np.where(np.asarray(used)[3:].reshape(-1, 3).any(-1), angles, 0.0)
    where = np.unravel_index(np.argmax(angles), angles.shape)
    return float(angles[where]), tuple(int(i) for i in where)


class InferenceInputError(ValueError):
    """Frames or an action given to MotionForecaster that it cannot predict from."""


def _future_len(future_len: int) -> int:
    # Up front: a float would fail deep in the decoding loop, 0 make a stream answer nothing.
    if not isinstance(future_len, numbers.Integral) or future_len < 1:
        raise InferenceInputError(f"future_len must be an integer >= 1, got {future_len!r}")
    return int(future_len)


class _FixedHorizon(nn.Module):  # the network with a fixed future_len, for export
    def __init__(self, net: nn.Module, future_len: int):
        super().__init__()
        self.net, self.future_len = net, future_len

    def forward(self, observed: Tensor, action: Tensor) -> Tensor:
        return self.net(observed, self.future_len, action=action)


# Each new (batch size, future_len) compiles again, tens of seconds; past this many shapes new
# ones run eagerly (one warning). Below torch's graph limit per function (recompile_limit, 8).
COMPILED_SHAPES = 4


def compile_for_prediction(net: nn.Module) -> nn.Module:
    """On a GPU "reduce-overhead" replays a prediction's hundreds of tiny kernels as one CUDA
    graph per shape; on the CPU the default mode fuses small ops. No fullgraph: networks of one
    class share torch's graph limit, past which torch runs eagerly instead of raising."""
    cuda = next(net.parameters()).device.type == "cuda"
    return torch.compile(net, mode="reduce-overhead" if cuda else "default", dynamic=False)


class MotionForecaster:
    """A trained predictor in eval mode: raw exp-map frames (..., F) at `fps` in and out."""

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
        """compile: True, False or "auto" (CUDA only); off by default: not reliably faster on CPU"""
        compiled(compile, cuda=False, name="compile")  # before the device's own errors
        # torch's own errors: an assertion at the first copy, or every device type listed.
        try:
            self.device = torch.device(device)
        except (RuntimeError, TypeError) as err:
            raise InferenceInputError(
                f"device={device!r} is not a torch device; use 'cpu', 'cuda' or 'cuda:N'"
            ) from err
        if self.device.type == "cuda" and not torch.cuda.is_available():
            raise InferenceInputError(
                f"device={device!r}, but this torch ({torch.__version__}) sees no CUDA device; "
                "use device='cpu'"
            )
        self.net = net.to(self.device).eval()
        self.compiled = compiled(compile, cuda=self.device.type == "cuda", name="compile")
        self._run = compile_for_prediction(self.net) if self.compiled else self.net
        self._shapes: set[tuple[int, int]] = set()  # compiled (batch size, future_len)
        self._warned = False
        self.normalizer = normalizer.to(self.device).eval()
        self.actions, self.observed_len, self.fps = list(actions), observed_len, float(fps)
        self.num_features = normalizer.num_features
        self._used = normalizer.used.cpu().numpy()  # for the degrees check, without a sync

    @classmethod
    def from_checkpoint(
        cls, path: str | Path, device: str = "cpu", compile: bool | str = False
    ) -> MotionForecaster:
        module = load_trained(path)
        observed_len = module.run_info["config"]["data"]["observed_len"]
        return cls(
            module.net, module.normalizer, module.actions, observed_len, device, compile,
            1000 / module.frame_ms,
        )  # fmt: skip

    def _step(self, fps: float | None) -> int:  # k: every k-th frame at k times the model's rate
        if fps is None:
            return 1
        if isinstance(fps, bool) or not isinstance(fps, numbers.Real) or not fps > 0:
            raise InferenceInputError(f"fps must be a positive number, got {fps!r}")
        step = round(fps / self.fps)
        if step < 1 or abs(fps / self.fps - step) > 1e-6:
            raise InferenceInputError(
                f"fps={fps:g}: this model forecasts from frames at {self.fps:g} fps, and {fps:g} "
                f"is no whole multiple of it; resample the frames to {self.fps:g} fps, or pass "
                f"frames at a multiple (fps={2 * self.fps:g}: every other one is used)"
            )
        return step

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

    def _frames(self, frames: np.ndarray | Tensor, shape: str) -> np.ndarray:
        if isinstance(frames, Tensor):  # bfloat16 has no numpy dtype: converted in torch
            frames = frames.detach().to("cpu", torch.float32)
        # C order: torch.as_tensor refuses the negative strides of np.flip or [::-1] views.
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
        if not np.isfinite(x).all():  # here, not on the device, where it would sync
            bad = np.argwhere(~np.isfinite(x))[0].tolist()
            raise InferenceInputError(f"frames hold NaN or inf (first at {bad}); clean them")
        # Frames in degrees would be forecast as if in radians, without a word.
        angle, where = largest_rotation(x, self._used)
        if angle > MAX_RADIANS:
            *frame, joint = where
            at = f"frame {frame}, " if frame else ""
            raise InferenceInputError(
                f"frames hold a joint rotation of {angle:.1f} ({at}columns {3 + 3 * joint}-"
                f"{5 + 3 * joint}); exp-map angles in radians stay within pi, so these look like "
                "degrees: convert them with np.deg2rad(frames)"
            )
        return x

    def _network(self, batch: int, future_len: int) -> nn.Module:
        """The compiled network for a shape it compiled or may still compile, else eager."""
        shape = (batch, future_len)
        if self.compiled and len(self._shapes) < COMPILED_SHAPES:
            self._shapes.add(shape)
        if not self.compiled or shape in self._shapes:
            return self._run
        if not self._warned:
            self._warned = True
            warnings.warn(
                f"MotionForecaster compiled {COMPILED_SHAPES} (batch size, future_len) shapes, "
                f"{sorted(self._shapes)}; {shape} and any other new shape run eagerly. Predict "
                "with fewer shapes (pad batches), or use compile=False.",
                stacklevel=4,  # the caller of predict (under inference_mode)
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
        """(observed_len, F) or (B, observed_len, F) raw frames -> (..., future_len, F), at
        `self.fps`. At fps= k times `self.fps`, k * observed_len frames: the newest and every
        k-th before it are used."""
        step = self._step(fps)
        T, F = self.observed_len * step, self.num_features
        shape = f"({T}, {F}) or (B, {T}, {F}) at {fps if step > 1 else self.fps:g} fps"
        x = self._frames(frames, shape)
        single = x.ndim == 2
        if x.ndim not in (2, 3) or x.shape[-2] != T:
            raise InferenceInputError(
                f"frames must be {shape}: the last {T} observed frames; got shape {x.shape}"
            )
        x = torch.as_tensor(x[None] if single else x, device=self.device)
        x = x[:, step - 1 :: step].contiguous()
        future_len, batch = _future_len(future_len), x.shape[0]
        pred = self._network(batch, future_len)(
            self.normalizer.normalize(x), future_len, action=self._action_ids(action, batch)
        )
        out = self.normalizer.unnormalize(pred).cpu().numpy()
        return out[0] if single else out

    def stream(
        self, action: str | None = None, future_len: int = 25, fps: float | None = None
    ) -> ForecastStream:
        """Push frames at `self.fps`, or at fps= k times it: then every k-th push, from the
        first, is used and answered, the others return None."""
        return ForecastStream(self, action, future_len, self._step(fps))

    def _fixed(self, future_len: int) -> tuple[nn.Module, tuple[Tensor, Tensor]]:
        """The normalised-space network for one future_len, and an example input to trace it."""
        observed = torch.zeros(1, self.observed_len, self.normalizer.pose_dim, device=self.device)
        action = torch.zeros(1, dtype=torch.long, device=self.device)
        return _FixedHorizon(self.net, future_len).eval(), (observed, action)

    def export_torchscript(self, path: str | Path, future_len: int = 25) -> Path:
        """Trace the normalised-space net, (observed (B, 50, D), action (B,) long) -> (B, T, D);
        the trace records the decoding loop, so the file predicts exactly future_len frames."""
        with torch.inference_mode(False), torch.no_grad():
            torch.jit.trace(*self._fixed(future_len), check_trace=False).save(str(path))
        return Path(path)

    def export_onnx(self, path: str | Path, future_len: int = 25) -> Path:
        """ONNX of the same normalised-space function, batch size dynamic."""
        torch.onnx.export(
            *self._fixed(future_len),
            str(path),
            input_names=["observed", "action"],
            output_names=["future"],
            dynamic_axes={"observed": {0: "batch"}, "action": {0: "batch"}, "future": {0: "batch"}},
            dynamo=False,
        )
        return Path(path)


class ForecastStream:
    """Frame-by-frame forecasting over a ring buffer of the last observed_len frames used: each
    push that fills it predicts from its window with `predict`."""

    def __init__(self, fc: MotionForecaster, action: str | None, future_len: int, step: int):
        fc._action_ids(action, 1)  # refused now, not at the observed_len-th frame
        self.fc, self.action, self.future_len = fc, action, _future_len(future_len)
        self.step, self.pushed = step, 0
        self.buffer: deque[np.ndarray] = deque(maxlen=fc.observed_len)

    def push(self, frame: np.ndarray) -> np.ndarray | None:
        """Add one raw frame (F,); returns (future_len, F) once observed_len frames were used."""
        F = self.fc.num_features
        x = self.fc._frames(frame, f"({F},)")
        if x.shape != (F,):
            raise InferenceInputError(f"push takes one frame of shape ({F},), got {x.shape}")
        self.pushed += 1
        if (self.pushed - 1) % self.step:
            return None
        self.buffer.append(x)
        if len(self.buffer) < self.fc.observed_len:
            return None
        return self.fc.predict(np.stack(self.buffer), self.action, self.future_len)
