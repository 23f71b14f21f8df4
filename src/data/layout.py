"""Where the files of each dataset live, relative to the data directory, and which ones a
configuration needs. H3.6M (protocol §1.1-1.2): ``h3.6m/dataset/S{subject}/{action}_{1,2}.txt``,
99 columns. CMU (§1.5): ``cmu_mocap/{train,test}/{action}/{action}_{k}.txt``, 117 columns, train
files k = 1..5, test file k = 1 (``walking_extra`` is never listed)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from src.data.errors import DataError

# Protocol §1.2, in [M]'s define_actions order (the index is the action label).
H36M_ACTIONS: tuple[str, ...] = tuple(
    "walking eating smoking discussion directions greeting phoning posing purchases sitting "
    "sittingdown takingphoto waiting walkingdog walkingtogether".split()
)
H36M_TRAIN_SUBJECTS: tuple[int, ...] = (1, 6, 7, 8, 9, 11)
H36M_TEST_SUBJECT = 5
# Protocol §1.5, [L] DataLoader_cmu.py order.
CMU_ACTIONS: tuple[str, ...] = tuple(
    "basketball basketball_signal directing_traffic jumping running soccer walking "
    "washwindow".split()
)


@dataclass(frozen=True)
class DatasetSpec:
    """Static facts about one dataset: its folder, archive, column count and action list."""

    name: str  # "h36m" or "cmu": cache folder and datamodule.dataset_name
    root: str  # top folder inside data_dir (and inside the archive)
    marker: str  # folder whose presence means "the dataset is unpacked"
    archive_name: str
    n_columns: int
    actions: tuple[str, ...]
    source: str  # where the archive comes from, for error messages
    url: str


H36M = DatasetSpec(
    name="h36m",
    root="h3.6m",
    marker="h3.6m/dataset",
    archive_name="h3.6m.zip",
    n_columns=99,
    actions=H36M_ACTIONS,
    source="h3.6m.zip as distributed with Martinez et al.'s code "
    "(github.com/una-dinosauria/human-motion-prediction)",
    url="http://www.cs.stanford.edu/people/ashesh/h3.6m.zip",
)
CMU = DatasetSpec(
    name="cmu",
    root="cmu_mocap",
    marker="cmu_mocap",
    archive_name="cmu_mocap.zip",
    n_columns=117,
    actions=CMU_ACTIONS,
    source="cmu_mocap.zip distributed with Li et al.'s code",
    url="https://github.com/chaneyddtt/Convolutional-Sequence-to-Sequence-Model-for-Human-Dynamics",
)
SPECS = {"h36m": H36M, "cmu": CMU}


@dataclass(frozen=True)
class FileEntry:
    """One expected motion file; ``key`` names its sequence (``S5/walking_1``, ``test/walking/
    walking_1``), ``index`` is the subaction (H3.6M) or file number k (CMU), 1-based."""

    action: str
    index: int
    subject: int | None
    relpath: str  # relative to data_dir
    key: str


def parse_actions(actions: str | Iterable[str], spec: DatasetSpec) -> list[str]:
    """The configured actions (``"all"``, a name, a comma-separated string or a list) in
    canonical order, which defines the action labels."""
    if isinstance(actions, str):
        actions = actions.split(",")
    names = [a for a in (str(a).strip() for a in actions) if a]
    if names == ["all"]:
        return list(spec.actions)
    unknown = [a for a in names if a not in spec.actions]
    if unknown or not names:
        raise DataError(
            f"unknown {spec.name} action(s) {unknown or names!r}; valid actions are 'all' or any "
            f"of: {', '.join(spec.actions)} (fix: set data.actions accordingly)"
        )
    return [a for a in spec.actions if a in names]


def h36m_files(subjects: Sequence[int], actions: Sequence[str]) -> list[FileEntry]:
    """The H3.6M files of ``subjects`` x ``actions`` x subactions 1, 2 (protocol §1.1)."""
    return [
        FileEntry(a, sub, s, f"{H36M.marker}/S{s}/{a}_{sub}.txt", f"S{s}/{a}_{sub}")
        for s in subjects
        for a in actions
        for sub in (1, 2)
    ]


def cmu_files(actions: Sequence[str], split: str) -> list[FileEntry]:
    """The CMU files of ``actions``: train k = 1..5, test k = 1 (protocol §1.5)."""
    count = 5 if split == "train" else 1
    return [
        FileEntry(a, k, None, f"{CMU.root}/{split}/{a}/{a}_{k}.txt", f"{split}/{a}/{a}_{k}")
        for a in actions
        for k in range(1, count + 1)
    ]


def missing_files(data_dir: str | Path, entries: Iterable[FileEntry]) -> list[str]:
    return [e.relpath for e in entries if not (Path(data_dir) / e.relpath).is_file()]
