"""jaxtyping aliases with named dimensions, shared by the offline modules.

Dimension names: ``V`` positions of one camera, ``C`` classes (object x pose),
``L`` occlusion levels, ``K`` eigenspace dimension, ``D = H*W`` pixels.
"""

from __future__ import annotations

from jaxtyping import Array, Float

__all__ = [
    "MeanImages",
    "Bases",
    "Eigenvalues",
    "Means",
    "Variances",
    "Cholesky",
]

MeanImages = Float[Array, "V D"]
Bases = Float[Array, "V D K"]
Eigenvalues = Float[Array, "V K"]
Means = Float[Array, "V C L K"]
Variances = Float[Array, "V C L K"]
Cholesky = Float[Array, "V C L K K"]
