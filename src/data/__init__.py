"""Data layer: text files -> arrays -> cache -> normalisation -> windows -> DataModules."""

from src.data.base import EvalWindow, MotionDataModule
from src.data.cmu import CMUDataModule
from src.data.errors import DataError
from src.data.h36m import H36MDataModule
from src.data.normalization import Normalizer
from src.data.synthetic import SyntheticDataModule, write_synthetic_h36m

__all__ = [
    "CMUDataModule",
    "DataError",
    "EvalWindow",
    "H36MDataModule",
    "MotionDataModule",
    "Normalizer",
    "SyntheticDataModule",
    "write_synthetic_h36m",
]
