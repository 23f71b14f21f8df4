"""Data layer: text files -> arrays -> cache -> normalisation -> windows -> DataModules."""

from src.data.cmu import CMUDataModule
from src.data.h36m import H36MDataModule
from src.data.synthetic import SyntheticDataModule

__all__ = ["CMUDataModule", "H36MDataModule", "SyntheticDataModule"]
