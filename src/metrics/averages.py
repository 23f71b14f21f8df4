"""The action sets an average error is taken over."""

from __future__ import annotations


def averages(evaluated: list[str], untrained) -> dict[str, tuple[list[str], str]]:
    """{name: (its actions, its set in words)} of the averages over evaluated actions that
    TensorBoard, the validation line and src.eval show: `average` over all of them, and, where
    some has no training files, `average_trained` over the others, the set src.report's verdict
    judges; with one set only its words are '' (a plain "average")."""
    trained = [a for a in evaluated if a not in untrained]
    if not trained or len(trained) == len(evaluated):
        return {"average": (list(evaluated), "")}
    return {
        "average": (list(evaluated), f"all {len(evaluated)} evaluated actions"),
        "average_trained": (trained, f"{len(trained)} trained actions"),
    }
