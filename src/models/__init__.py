"""Plain nn.Module predictors. Every predictor implements

    forward(observed (B, 50, D), future_len, action=None, future=None, eta=1.0) -> (B, T, D)

in the normalised used-dimension space (docs/architecture.md); HisRep takes the raw used
exp-map dims instead (src/models/hisrep.py).
"""

from src.models.baselines import RunningAverage, ZeroVelocity
from src.models.conv_encoder import ConvEncoder
from src.models.conv_s2s import ConvSeq2Seq
from src.models.discriminator import Discriminator
from src.models.gru_s2s import GRUSeq2Seq
from src.models.hisrep import HisRep

__all__ = [
    "ConvEncoder",
    "ConvSeq2Seq",
    "Discriminator",
    "GRUSeq2Seq",
    "HisRep",
    "RunningAverage",
    "ZeroVelocity",
]
