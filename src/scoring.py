"""The test windows as arrays for models outside the project (`window_arrays`, which
`src.export_windows` writes), and `src.eval predictions=<file>`: their predictions by any code
(format: README, "Scoring a model from another code base"), checked, then standing in for
the network in src.eval's own test loop (FilePredictor). An action is predicted fully or not at
all (then reported absent)."""

from __future__ import annotations

import hashlib
import itertools
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig
from torch import Tensor

from src.build import build_test_data
from src.config import ConfigError
from src.data.base import MotionDataModule, window_ids
from src.data.layout import SPECS
from src.inference import MAX_RADIANS, largest_rotation
from src.lit.parts import data_facts
from src.lit.predictor import MotionPredictor
from src.metrics.euler_error import horizon_frame_indices
from src.reporting.published import find_published, published_datasets

OPTIONAL = ("model", "dataset", "protocol", "data_sha256")
SAVE = "np.savez(path, prediction=<(N, T, F) raw exp-map>, window_id=<windows.npz's window_id>)"


def windows_sha256(ids: Iterable[str], frames: Iterable[np.ndarray]) -> str:
    """SHA-256 over each window's id and its observed + future frames (float32, C order), in
    the protocol's order: equal for equal windows, whoever computes it from whatever copy."""
    digest = hashlib.sha256()
    for name, window in zip(ids, frames, strict=True):
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(window, dtype=np.float32).tobytes())
    return digest.hexdigest()


def window_arrays(dm: MotionDataModule, dataset: str) -> dict[str, np.ndarray]:
    """A set-up datamodule's test windows as `src.export_windows` writes them, in order:
    - ``observed`` (N, observed_len, F), ``future`` (N, future_len, F): raw exp-map frames,
      float32, downsampled as everywhere (§1.3); F = 99 on H3.6M, 117 on CMU;
    - ``action``, ``window_id`` (`window_ids`): (N,) strings; 0-d metadata: ``dataset`` (the data
      config's name: ``synthetic`` is not H3.6M), ``protocol``, ``fps`` (25, on CMU too, as the
      tables' horizons assume, protocol §1.5), ``data_sha256`` (`windows_sha256`)."""
    frames = np.stack([dm.raw_window(i) for i in range(len(dm.eval_windows))])
    ids = window_ids(dm.eval_windows)
    return {
        "observed": frames[:, : dm.observed_len],
        "future": frames[:, dm.observed_len :],
        "action": np.array([w.action for w in dm.eval_windows]),
        "window_id": np.array(ids),
        "dataset": np.array(dataset),
        "protocol": np.array(dm.eval_protocol),
        "fps": np.array(1000.0 / dm.frame_ms),
        "data_sha256": np.array(windows_sha256(ids, frames)),
    }


class PredictionsError(ConfigError):
    """A predictions file that cannot be scored."""


def refuse_transposed(path: Path, shape: tuple[int, ...], expected: tuple) -> None:
    """Name a transposed prediction as such: its other checks would blame window_id or say it
    has `frames` columns. `expected`: (windows, frames, columns), None where not known yet (then
    any number of frames, a dataset's number of columns)."""
    windows, frames, columns = expected
    for axes in itertools.permutations(range(3)):
        n, t, f = (shape[a] for a in axes)
        known = f == columns if columns else f in {s.n_columns for s in SPECS.values()}
        if axes != (0, 1, 2) and n == windows and frames in (None, t) and known:
            raise PredictionsError(
                f"{path}: prediction has shape {shape}, (windows, frames, columns) = {(n, t, f)} "
                f"was expected: it looks transposed; save prediction.transpose{axes}"
            )


@dataclass
class Predictions:
    path: Path
    prediction: np.ndarray  # (N, T, F) float32
    ids: list[str]
    meta: dict[str, str]  # the OPTIONAL entries it has


def read_predictions(path: str | Path) -> Predictions:
    """Read and check what needs no data: the arrays' presence, types, shapes, finite values."""
    path = Path(path)
    if not path.is_file():
        raise PredictionsError(f"predictions file not found: {path}. Save one with {SAVE}")
    try:
        npz = np.load(path, allow_pickle=False)
    except Exception as err:  # numpy raises several types for a file that is not an array
        raise PredictionsError(
            f"{path} is not a .npz file numpy can read ({str(err).splitlines()[0][:200]}); "
            f"save the predictions with {SAVE}"
        ) from err
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise PredictionsError(f"{path} holds one array, not a .npz of named arrays: {SAVE}")
    with npz:
        if missing := [k for k in ("prediction", "window_id") if k not in npz.files]:
            raise PredictionsError(
                f"{path} has no {' and no '.join(missing)} array (it holds: "
                f"{', '.join(npz.files) or 'nothing'}); save it with {SAVE}"
            )
        arrays = {}
        for key in ("prediction", "window_id", *[k for k in OPTIONAL if k in npz.files]):
            try:
                arrays[key] = npz[key]
            except ValueError as err:  # object arrays: loading them would unpickle
                raise PredictionsError(
                    f"{path}: {key} is an array of Python objects, not loaded (unpickling can "
                    "run code); save plain numbers or strings: np.asarray(..., dtype=float or str)"
                ) from err
    prediction, ids = arrays.pop("prediction"), arrays.pop("window_id")
    if prediction.dtype.kind not in "fiu" or prediction.ndim != 3 or not len(prediction):
        raise PredictionsError(
            f"{path}: prediction is {prediction.dtype} of shape {prediction.shape}; it must hold "
            "numbers and it must be (N, T, F) with N >= 1: T raw exp-map frames per window"
        )
    if ids.ndim == 1 and len(ids) != len(prediction):
        refuse_transposed(path, prediction.shape, (len(ids), None, None))
    if ids.dtype.kind not in "US" or ids.shape != (len(prediction),):
        raise PredictionsError(
            f"{path}: window_id is {ids.dtype} of shape {ids.shape}, {ids.size} window ids for "
            f"{len(prediction)} predictions; it must be a 1-D array of strings, windows.npz's ids"
        )
    for key, value in arrays.items():
        if value.dtype.kind not in "US" or value.size != 1:
            raise PredictionsError(
                f"{path}: {key} must be one string (as windows.npz's), got a {value.dtype} "
                f"array of shape {value.shape}"
            )
    ids = ids.astype(str).tolist()
    bad = ~np.isfinite(prediction)
    if bad.any():
        row, frame, col = np.argwhere(bad)[0].tolist()
        raise PredictionsError(
            f"{path}: prediction holds {int(bad.sum())} NaN or inf value(s), the first in window "
            f"{ids[row]!r} (row {row}), frame {frame}, column {col}; predict finite values"
        )
    meta = {key: str(value.astype(str).item()) for key, value in arrays.items()}
    return Predictions(path, prediction.astype(np.float32, copy=False), ids, meta)


def match_windows(preds: Predictions, dm: MotionDataModule, dataset: str) -> dict[str, str]:
    """Check the file against the datamodule's windows; return the actions it has no
    predictions for, {action: reason}."""
    path, (_, T, F), protocol = preds.path, preds.prediction.shape, dm.eval_protocol
    export = f"`python -m src.export_windows data={dataset} protocol={protocol}`"
    expected = (len(preds.ids), dm.future_len, dm.num_features)
    if preds.prediction.shape != expected:
        refuse_transposed(path, preds.prediction.shape, expected)
    if F != dm.num_features:
        others = [s.name for s in SPECS.values() if s.n_columns == F]
        why = f"give raw exp-map frames of {dm.num_features} columns, as windows.npz's"
        if F == dm.pose_dim:
            why = f"{F} is the number of normalised columns the models use inside; {why}"
        elif others:
            why = f"a file for {others[0]}? score it with data={others[0]}"
        raise PredictionsError(
            f"{path}: prediction has {F} columns per frame, {dataset} frames have "
            f"{dm.num_features}: {why}"
        )
    need = dm.future_len
    if T < need:
        beyond = [ms for ms, k in horizon_frame_indices(dm.frame_ms, need).items() if k >= T]
        column = f", and the table's {beyond[0]} ms column needs {beyond[0] // dm.frame_ms}"
        raise PredictionsError(
            f"{path}: prediction has {T} frames per window{column if beyond else ''}: predict "
            f"{need} frames (data.future_len), or score fewer horizons with data.future_len={T} "
            "(export the windows with it too)"
        )
    if T > need:
        raise PredictionsError(
            f"{path}: prediction has {T} frames per window, the protocol scores {need} "
            f"(data.future_len): save the first {need}, prediction[:, :{need}]"
        )
    # Else degrees would be scored, without a word, as an error of some 10 rad at every horizon.
    angle, (row, frame, joint) = largest_rotation(preds.prediction, dm.normalizer.used.numpy())
    if angle > MAX_RADIANS:
        raise PredictionsError(
            f"{path}: prediction holds a joint rotation of {angle:.1f} (window {preds.ids[row]!r}, "
            f"frame {frame}, columns {3 + 3 * joint}-{5 + 3 * joint}); exp-map angles in radians "
            "stay within pi, so these look like degrees: convert them with np.deg2rad(prediction)"
        )
    counts = Counter(preds.ids)
    if repeated := [i for i, n in counts.items() if n > 1]:
        raise PredictionsError(
            f"{path}: window_id {repeated[0]!r} appears {counts[repeated[0]]} times "
            f"({len(repeated)} id(s) repeated); give one prediction per window"
        )
    ours = window_ids(dm.eval_windows)
    known = set(ours)
    if unknown := [i for i in preds.ids if i not in known]:
        absent = ", ".join(dm.absent_actions)
        absent = f"; this data copy cannot evaluate {absent}" if absent else ""
        raise PredictionsError(
            f"{path}: {len(unknown)} of {len(preds.ids)} window ids are not {dataset} "
            f"protocol={protocol} test windows (e.g. {unknown[0]!r}{absent}): a file for another "
            f"protocol, dataset or data.future_len? Predict the windows of {export}"
        )
    absent = {}
    for action in dm.actions:
        names = [n for n, w in zip(ours, dm.eval_windows, strict=True) if w.action == action]
        lacking = [n for n in names if n not in counts]
        if names and len(lacking) == len(names):
            absent[action] = f"no predictions in {path.name}"
        elif lacking:
            raise PredictionsError(
                f"{path}: {len(lacking)} of the {len(names)} {action} windows have no prediction "
                f"(e.g. {lacking[0]!r}); predict all of them, or none to leave {action} out"
            )
    sha = preds.meta.get("data_sha256")
    if sha is not None and sha != str(window_arrays(dm, dataset)["data_sha256"]):
        raise PredictionsError(
            f"{path}: its data_sha256 is not that of the windows here: exported from other data "
            f"(other archives or data.* settings); predict the windows of {export} run here"
        )
    return absent


def published_ref(value: str | None, dataset: str) -> dict | None:
    """`published=PAPER:METHOD` as a model config's `published` entry; None for none."""
    if value in (None, "", "none"):
        return None
    paper, _, method = str(value).partition(":")
    papers = {p for p, _ in find_published(dataset, method)}
    if dataset in published_datasets() and paper not in papers:
        raise ConfigError(
            f"published={value}: no published {dataset} numbers of that paper and method; use "
            "PAPER:METHOD of src/reporting/published_results.csv (li2018:conv_s2s) or none"
        )
    return {"paper": paper, "method": method}


class FilePredictor(MotionPredictor):
    """The file's predictions in place of the network's. The columns the protocol ignores (§2.1)
    are set to their training mean, as unnormalising a network's output does."""

    def __init__(self, preds: Predictions, dm: MotionDataModule, dim_rule: str, config: dict):
        super().__init__(  # untrained actions: of this copy, as for a baseline
            model={"net": {"_target_": "torch.nn.Identity"}},
            data=data_facts(dm),
            metrics={"dim_rule": dim_rule},
            normalizer=dm.normalizer,
        )
        self.run_info = {"config": config}
        row_of = {name: row for row, name in enumerate(preds.ids)}
        rows = [row_of[name] for name in window_ids(dm.eval_windows)]  # row i: eval window i
        self.register_buffer("prediction", torch.from_numpy(preds.prediction[rows]), False)

    def predict_windows(self, batch: dict[str, Tensor]) -> Tensor:
        used, mean = self.normalizer.used, self.normalizer.mean
        return torch.where(used, self.prediction[batch["window"]], mean)


def score_predictions(cfg: DictConfig) -> tuple[MotionDataModule, FilePredictor]:
    """(datamodule of the windows scored, module to test) for src.eval, from
    `predictions=<file> data=<name> [protocol=...] [published=PAPER:METHOD]`."""
    if cfg.get("ckpt_path") or cfg.get("model") is not None:
        raise ConfigError("predictions= scores a file on its own: drop ckpt_path= and model=")
    if cfg.get("data") is None:
        raise ConfigError(
            f"say whose test windows {cfg.predictions} predicts: data=h36m|cmu|synthetic "
            "(and protocol=srnn|random|strided)"
        )
    dataset, preds = cfg.data.name, read_predictions(cfg.predictions)
    # What the file says it was made for, checked before the data are read.
    protocol = cfg.get("protocol") or cfg.data.eval_protocol
    for key, ours in (("dataset", dataset), ("protocol", protocol)):
        theirs = preds.meta.get(key, ours)
        if theirs != ours:
            raise PredictionsError(
                f"{preds.path} holds predictions for {key} {theirs} (its {key!r} entry), not "
                f"{ours}: score it with {'data' if key == 'dataset' else key}={theirs}, or "
                f"predict the windows of `python -m src.export_windows data={dataset} "
                f"protocol={protocol}`"
            )
    published = published_ref(cfg.get("published"), dataset)
    dm = build_test_data(cfg)
    dm.leave_out(match_windows(preds, dm, dataset))
    model = {"name": preds.meta.get("model") or preds.path.stem, "published": published}
    config = {"model": model, "data": {"name": dataset}}
    return dm, FilePredictor(preds, dm, cfg.metrics.dim_rule, config)
