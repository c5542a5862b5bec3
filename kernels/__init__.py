"""Pure JAX estimation kernels (likelihood, belief, mutual information, Fisher /
Cramér-Rao), each with a plain NumPy reference in :mod:`jaxrecog.kernels.reference`.

Nothing here imports from ``jaxrecog`` proper or ``jaxrecog.hardware``.
"""
