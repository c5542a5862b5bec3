"""jaxtyping aliases with named dimensions, shared by the offline modules.

Dimension names: ``V`` positions of one camera, ``C`` classes (object x pose),
``L`` occlusion levels, ``K`` eigenspace dimension, ``D = H*W`` pixels,
``B`` a batch, ``N`` database rows.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Array, Bool, Float, Int, UInt8

__all__ = [
    "GrayImage",
    "ImageStack",
    "ImageVectors",
    "Features",
    "FeatureBatch",
    "MeanImages",
    "Bases",
    "Eigenvalues",
    "Means",
    "Variances",
    "Cholesky",
    "ValidMask",
    "IntVector",
]

GrayImage = UInt8[np.ndarray, "H W"]
ImageStack = UInt8[np.ndarray, "B H W"]
ImageVectors = Float[Array, "B D"]
Features = Float[Array, " K"]
FeatureBatch = Float[Array, "B K"]
MeanImages = Float[Array, "V D"]
Bases = Float[Array, "V D K"]
Eigenvalues = Float[Array, "V K"]
Means = Float[Array, "V C L K"]
Variances = Float[Array, "V C L K"]
Cholesky = Float[Array, "V C L K K"]
ValidMask = Bool[Array, " B"]
IntVector = Int[np.ndarray, " N"]
