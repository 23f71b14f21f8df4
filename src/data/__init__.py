"""Data layer: text files -> arrays -> cache -> normalisation -> windows -> DataModules."""
