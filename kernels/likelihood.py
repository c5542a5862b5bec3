"""The sensor-model seam: one likelihood interface per camera, the registry of
its kinds, and the per-camera log-likelihood arrays of one step (thesis
eq. 4.17-4.22).

For camera i at position v the sensor model is a density p(g | c, k, v) of the
eigenspace features g for every class c and occlusion level k (eq. 4.18-4.19);
cameras are conditionally independent given the state, so the joint
log-likelihood is the sum over cameras (eq. 4.17).  Everything the estimation
code needs from a family is, per camera and position:

- ``log_density(g)``: log p(g | c, k, v) for every (c, k), ``[..., C, L]``;
- ``sample(z)``: g ~ p(g | c, k, v) from standard-normal draws z (the
  planners' common random numbers);
- ``mean()`` / ``covariance()``: the per-component moments;
- ``bhattacharyya()`` / ``kl()``: the closed-form pairwise divergences
  between components where the family has one, and ``divergence(kind)``, the
  table the pairwise-distance MI planner uses (the closed form, or a
  moment-matched Gaussian approximation for a family without one);
- ``scaled(factor)``: the family with its dispersion scaled per level (what
  calibration fits).

As in dynamax (inference takes log-likelihood arrays; emissions are their own
class), the kernels take *arrays*: :func:`jaxrecog.kernels.update` takes the
tuple of ``[C, L_i]`` arrays of :func:`camera_log_likelihoods`, the planners
take the sample tables :func:`jaxrecog.kernels.mi_tables` builds with
``sample`` and ``log_density``.  No formula is written outside a family's own
file (``gaussian_diag.py``: the thesis's diagonal Gaussian; ``gaussian_full.py``:
the full-covariance option).

Layout: a camera's likelihood holds all its positions, every array field with
a leading position axis ``V`` (``field_shapes`` names the axes).  ``lik.at(v)``
is the component set of one position (arrays ``[C, L, ...]``); the methods act
on one position (``jax.vmap`` / ``lax.map`` over a camera's likelihood maps
over its positions).

Registry: :data:`LIKELIHOODS` maps a kind name (recorded in the model file)
to its class; a family registers itself with ``@register_likelihood``.  A new
family is one file (a :class:`Likelihood` subclass with the decorator) plus the
import that registers it (``kernels/__init__.py`` for the built-in ones); the
model file saves and loads its arrays generically from ``field_shapes``.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

__all__ = [
    "DEFAULT_LIKELIHOOD",
    "DEFAULT_VIEW_JITTER_LIKELIHOOD",
    "LIKELIHOODS",
    "Likelihood",
    "as_likelihoods",
    "camera_log_likelihoods",
    "gaussian",
    "gaussian_likelihoods",
    "likelihood_class",
    "likelihood_names",
    "register_likelihood",
]

#: The sensor-model family trained when none is named (``jaxrecog train``,
#: ``campaigns.Settings``): the thesis's diagonal Gaussian (eq. 4.12).
#: docs/results.md ("Training against confident errors") gives the measured
#: reason it stays the default: no other family wins every case.
DEFAULT_LIKELIHOOD = "gaussian-diag"

#: The family trained when none is named but the training has view jitter
#: (``jaxrecog train --view-jitter``, ``experiment`` / ``reproduce_thesis.py
#: --view-jitter``): one low-rank component per rendered view
#: (``view_mixture.py``).  docs/results.md ("View mixtures") gives the measured
#: reason: it wins every case against pooling the jitter views into one
#: diagonal Gaussian and against the thesis's model.
DEFAULT_VIEW_JITTER_LIKELIHOOD = "view-mixture-lowrank"

LIKELIHOODS: dict[str, type["Likelihood"]] = {}
"""Kind name -> :class:`Likelihood` subclass (filled by :func:`register_likelihood`)."""


def check_divergence(kind: str) -> None:
    if kind not in ("bhattacharyya", "kl"):
        raise ValueError(f"divergence: kind must be 'bhattacharyya' or 'kl', got {kind!r}")


class Likelihood(eqx.Module):
    """p(g | c, k, v) of one camera: the interface every sensor-model family implements.

    Class attributes (per family):
        kind: the registry name, recorded in the model file.
        field_shapes: array field name -> its axes in a camera's likelihood,
            e.g. ``{"mu": "V C L K", "var": "V C L K"}`` (``V`` positions,
            ``C`` classes, ``L`` levels, ``K`` feature dimension; other
            letters are the family's own sizes).  The model file saves exactly
            these arrays and checks their shapes on load.
        second_moments: what training accumulates for :meth:`fit`: ``"diag"``
            (per-dimension second moments) or ``"full"`` (``K x K``).
        name: the user-facing name (``jaxrecog train --likelihood``); default
            the kind.  :func:`likelihood_class` accepts either.
        fit_options: the keyword options :meth:`fit` takes (e.g. ``("rank",)``);
            training rejects any other before it starts.
        calibration_shapes: names of the per-level shape parameters that
            calibration fits besides the variance factor (e.g. ``("nu",)``),
            through :meth:`calibrated_log_density` / :meth:`shape_shifted`.
        derived_shapes: arrays the family computes from its stored fields
            when it is built (``__init__``), e.g. a factorisation its density
            reuses at every capture; never stored by the model file (which
            rebuilds them on load through :meth:`from_arrays`), sliced and
            stacked with the stored fields like any other leaf.
        view_components: ``True`` for a family with one component per
            rendered view of a class (the training image, then each of the
            database's ``jitter`` images of that view): training then passes
            :meth:`fit` per-component moments ``[C, L, M, K]`` and needs view
            jitter (``view_mixture.py``).
        summary_words: how a model summary (``SensorModel.summary``, ``jaxrecog
            inspect``) names the family's kind and its components when every
            camera has it: ``(label, plural)``, default ``("likelihood",
            "likelihood components")``; the thesis's Gaussians keep their
            ``("covariance", "Gaussians")``.
    """

    kind: ClassVar[str]
    field_shapes: ClassVar[dict[str, str]]
    second_moments: ClassVar[str] = "diag"
    name: ClassVar[str | None] = None
    fit_options: ClassVar[tuple[str, ...]] = ()
    calibration_shapes: ClassVar[tuple[str, ...]] = ()
    derived_shapes: ClassVar[dict[str, str]] = {}
    view_components: ClassVar[bool] = False
    summary_words: ClassVar[tuple[str, str]] = ("likelihood", "likelihood components")

    def __check_init__(self):
        self.sizes()  # consistent axes across fields (raises otherwise)

    # ------------------------------------------------------------ sizes and layout

    def sizes(self) -> dict[str, int]:
        """Axis name -> size, read from the fields (aligned from the right, so a
        one-position set simply has no ``V``)."""
        out: dict[str, int] = {}
        for name, spec in self.field_shapes.items():
            axes = spec.split()
            shape = tuple(np.shape(getattr(self, name)))
            if len(shape) not in (len(axes), len(axes) - 1):
                raise ValueError(f"{type(self).__name__}: {name} has shape {shape}, expected [{spec}] "
                                 f"(or one position, without V)")
            for a, s in zip(reversed(axes), reversed(shape)):
                if out.setdefault(a, s) != s:
                    raise ValueError(f"{type(self).__name__}: {name} has {a} = {s}, another field has {a} = {out[a]}")
        return out

    @property
    def n_positions(self) -> int:
        """V (a camera's likelihood; a one-position set has none)."""
        sizes = self.sizes()
        if "V" not in sizes:
            raise ValueError(f"{type(self).__name__}: a one-position component set has no position axis")
        return sizes["V"]

    @property
    def n_classes(self) -> int:
        return self.sizes()["C"]

    @property
    def n_levels(self) -> int:
        return self.sizes()["L"]

    @property
    def dim(self) -> int:
        """K, the feature dimension."""
        return self.sizes()["K"]

    @property
    def dtype(self):
        return jnp.result_type(getattr(self, next(iter(self.field_shapes))))

    @property
    def noise_dim(self) -> int:
        """Standard-normal numbers per draw that :meth:`sample` takes (default K)."""
        return self.dim

    def at(self, v: Int[Array, ""] | int) -> "Likelihood":
        """The component set of position ``v`` (may be traced): every field indexed by ``v``."""
        return jax.tree.map(lambda x: x[v], self)

    def arrays(self) -> dict[str, Array]:
        """The arrays the model file stores (``field_shapes`` order)."""
        return {name: getattr(self, name) for name in self.field_shapes}

    @classmethod
    def from_arrays(cls, arrays: dict[str, Array]) -> "Likelihood":
        """The inverse of :meth:`arrays` (the model file's generic load)."""
        return cls(**arrays)

    def problems(self) -> list[tuple[str, str]]:
        """Host-side checks of the values, as ``(field, what is wrong)`` pairs
        (e.g. ``("var", "has non-positive variances")``); shapes, dtype and
        finiteness are checked by the model file.  Default: none."""
        return []

    # ------------------------------------------------------------ the family (one position)

    @abc.abstractmethod
    def log_density(self, g: Float[Array, "*B K"]) -> Float[Array, "*B C L"]:
        """log p(g | c, k) for every class c and level k, for each of the
        feature vectors ``g`` (any leading batch axes ``B``)."""

    @abc.abstractmethod
    def sample(self, z: Float[Array, "C L J Z"]) -> Float[Array, "C L J K"]:
        """Draw j of component (c, k) from the standard-normal numbers
        ``z[c, k, j]`` (``Z = noise_dim``): g[c, k, j] ~ p(g | c, k)."""

    @abc.abstractmethod
    def mean(self) -> Float[Array, "C L K"]:
        """E[g | c, k]."""

    @abc.abstractmethod
    def covariance(self) -> Float[Array, "C L K K"]:
        """Cov[g | c, k]."""

    @abc.abstractmethod
    def scaled(self, factor: Float[Array, " L"]) -> "Likelihood":
        """The same family with its dispersion scaled so that the covariance of
        every component of level k is ``factor[k]`` times the present one
        (calibration's variance inflation)."""

    def variance(self) -> Float[Array, "C L K"]:
        """The diagonal of :meth:`covariance`."""
        return jnp.diagonal(self.covariance(), axis1=-2, axis2=-1)

    def bhattacharyya(self) -> Float[Array, "C L C L"]:
        """D_B(c, k; c', k') = -log ∫ sqrt(p(g|c,k) p(g|c',k')) dg for every pair
        of components (closed form where the family has one).

        Raises:
            NotImplementedError: the family has no closed form (the default); a
                pairwise-distance planner then needs a documented approximation.
        """
        raise NotImplementedError(f"the {self.kind!r} likelihood has no closed-form Bhattacharyya distance")

    def kl(self) -> Float[Array, "C L C L"]:
        """KL(p(g|c,k) || p(g|c',k')) = ∫ p(g|c,k) log [p(g|c,k) / p(g|c',k')] dg
        for every ordered pair of components (closed form where the family has one).

        Raises:
            NotImplementedError: the family has no closed form (the default); see
                :meth:`divergence` for the approximation the planners use then.
        """
        raise NotImplementedError(f"the {self.kind!r} likelihood has no closed-form KL divergence")

    def divergence(self, kind: str) -> Float[Array, "C L C L"]:
        """The pairwise divergence table D[c, k, c', k'] of the pairwise-distance
        MI planner (:func:`jaxrecog.kernels.pairwise_tables`), ``kind`` =
        ``"bhattacharyya"`` or ``"kl"``.

        The family's closed form (:meth:`bhattacharyya` / :meth:`kl`) where it
        has one.  Otherwise an *approximation*: the same divergence between the
        moment-matched Gaussians N(mean(), covariance()) of the components (the
        full-covariance closed form of the family registered as ``"full"``,
        ``gaussian_full.py``, taken from :data:`LIKELIHOODS`: this module
        imports no family).  For a heavy-tailed
        family this is not a bound any more (the pairwise estimator's bounds hold
        for the exact divergences); it is exact where the family is Gaussian.
        """
        check_divergence(kind)
        try:
            return self.bhattacharyya() if kind == "bhattacharyya" else self.kl()
        except NotImplementedError:
            return self.moment_matched_divergence(kind)

    def camera_divergence(self, kind: str) -> Float[Array, "V C L C L"]:
        """:meth:`divergence` at every position of a camera's likelihood,
        ``[V, C, L, C', L']``, one position at a time.  A family may override
        it with a faster evaluation of the same closed form (equal to rounding;
        the pruned planner computes its live classes' tables at every step)."""
        return jax.lax.map(lambda lik_v: lik_v.divergence(kind), self)

    def moment_matched_divergence(self, kind: str) -> Float[Array, "C L C L"]:
        """The divergence ``kind`` between the moment-matched Gaussians
        N(mean(), covariance()) of the components (:meth:`divergence`'s
        approximation for a family without a closed form)."""
        check_divergence(kind)
        matched = likelihood_class("full").from_moments(self.mean(), self.covariance())
        return matched.bhattacharyya() if kind == "bhattacharyya" else matched.kl()

    def scaling_terms(self, g: Float[Array, "N K"]):
        """Whatever :meth:`scaled_log_density` needs from the features ``g``,
        computed once (calibration evaluates many factors on the same ``g``).
        Default: ``g`` itself."""
        return g

    def scaled_log_density(self, terms, log_factor: Float[Array, " L"]) -> Float[Array, "N C L"]:
        """``scaled(exp(log_factor)).log_density(g)`` from ``terms = scaling_terms(g)``
        (default: exactly that; a family may override it with a cheaper form)."""
        return self.scaled(jnp.exp(log_factor)).log_density(terms)

    def calibrated_log_density(self, terms, log_factor: Float[Array, " L"],
                               shape: Float[Array, "L P"]) -> Float[Array, "N C L"]:
        """:meth:`scaled_log_density` with the shape parameters moved by ``shape``
        (``[L, P]``, ``P = len(calibration_shapes)``, unconstrained offsets; see
        :meth:`shape_shifted`).  Default (no shape parameters): the scaled density."""
        return self.scaled_log_density(terms, log_factor)

    def shape_shifted(self, shape: Float[Array, "L P"]) -> "Likelihood":
        """The likelihood with its shape parameters moved by the offsets ``shape``
        (what calibration applies after the variance factors).  Default: itself."""
        return self

    @classmethod
    def with_defaults(cls, **options) -> dict:
        """The fit options a model file and an experiment's cache key record:
        those given, plus the default of any option whose default changed
        after models were trained without it (so an older model is never
        taken for a newer one).  Default: the options as given."""
        return dict(options)

    @classmethod
    def holdout_fraction(cls, **options) -> float:
        """The fraction of each component's training samples that :meth:`fit`
        wants held out of the moments (passed to it as ``holdout``), for the
        given options.  Default: none."""
        return 0.0

    @classmethod
    def fit(cls, mean: np.ndarray, second: np.ndarray, floor: np.ndarray, **options) -> "Likelihood":
        """Fit one position from the training samples' moments (eq. 4.23-4.24).

        Args:
            mean: ``[C, L, K]`` sample means.
            second: ``[C, L, K]`` sample variances (``second_moments="diag"``)
                or ``[C, L, K, K]`` sample covariances (``"full"``).
            floor: ``[C, L]`` variance floor that keeps every component proper.
            **options: the family's own settings (names in ``fit_options``)
                and, when :meth:`holdout_fraction` is positive, ``holdout =
                (g [N, K], cls [N], level [N])``: the held-out samples.

        Raises:
            NotImplementedError: the family cannot be fitted from moments (the default).
        """
        raise NotImplementedError(f"the {cls.kind!r} likelihood cannot be trained from sample moments")


def register_likelihood(cls: type[Likelihood]) -> type[Likelihood]:
    """Add ``cls`` to :data:`LIKELIHOODS` under ``cls.kind`` (usable as a class decorator)."""
    if not (isinstance(cls, type) and issubclass(cls, Likelihood)):
        raise TypeError(f"register_likelihood: {cls!r} is not a Likelihood subclass")
    kind = getattr(cls, "kind", None)
    if not isinstance(kind, str) or not kind:
        raise ValueError(f"register_likelihood: {cls.__name__} has no `kind` name")
    if LIKELIHOODS.get(kind, cls) is not cls:
        raise ValueError(f"register_likelihood: kind {kind!r} is already {LIKELIHOODS[kind].__name__}")
    LIKELIHOODS[kind] = cls
    return cls


def likelihood_class(kind: str) -> type[Likelihood]:
    """The registered class of ``kind`` (its kind or its user-facing ``name``);
    a ``ValueError`` naming the known kinds otherwise."""
    try:
        return LIKELIHOODS[kind]
    except (KeyError, TypeError):
        pass
    for cls in LIKELIHOODS.values():
        if cls.name is not None and cls.name == kind:
            return cls
    raise ValueError(f"unknown likelihood {kind!r}; registered: {', '.join(sorted(LIKELIHOODS))}") from None


def likelihood_names(trainable: bool = True) -> tuple[str, ...]:
    """The user-facing names (``name``, else the kind) of the registered families,
    in registration order; ``trainable``: only those with a :meth:`Likelihood.fit`."""
    return tuple(cls.name or kind for kind, cls in LIKELIHOODS.items()
                 if not trainable or cls.fit.__func__ is not Likelihood.fit.__func__)


def gaussian(mu, var=None, chol=None) -> Likelihood:
    """The thesis's Gaussian from its arrays: ``"diag"`` from ``var``, or
    ``"full"`` from the lower Cholesky factor ``chol`` (then ``var``, if given,
    is the diagonal of the covariance)."""
    if chol is None:
        return likelihood_class("diag")(mu, var)
    return likelihood_class("full")(mu, chol, var)


def gaussian_likelihoods(mus, vars=None, chols=None, *, where: str = "gaussian_likelihoods") -> tuple[Likelihood, ...]:
    """Per-camera Gaussians (:func:`gaussian`) from ``mus`` (``[V_i, C, L_i, K_i]``
    per camera) and exactly one of ``vars`` (diagonal, the same shapes) or
    ``chols`` (full covariance, ``[V_i, C, L_i, K_i, K_i]``), shapes checked
    (``where`` prefixes the errors): what the kernels take for arrays."""
    if (vars is None) == (chols is None):
        raise ValueError(f"{where}: give exactly one of `vars` (diagonal) or `chols` (full)")
    other = vars if vars is not None else chols
    if len(other) != len(mus) or len(mus) == 0:
        raise ValueError(f"{where}: {len(mus)} mean arrays but {len(other)} covariance arrays")
    c = mus[0].shape[1] if mus[0].ndim == 4 else None
    for i, mu in enumerate(mus):
        if mu.ndim != 4 or mu.shape[1] != c:
            raise ValueError(f"{where}: mus[{i}] must be [V, C={c}, L, K], got {mu.shape}")
        want = mu.shape if vars is not None else mu.shape + mu.shape[-1:]
        if other[i].shape != want:
            raise ValueError(f"{where}: covariance of camera {i} has shape {other[i].shape}, want {want}")
    if vars is not None:
        return tuple(gaussian(m, v) for m, v in zip(mus, vars))
    return tuple(gaussian(m, chol=ch) for m, ch in zip(mus, chols))


def as_likelihoods(likelihoods, *, where: str = "likelihoods") -> tuple[Likelihood, ...]:
    """The per-camera :class:`Likelihood` s (each over its positions) as a
    tuple, checked: every camera has a position axis and the same classes.
    Arrays are refused with a ``TypeError`` naming :func:`gaussian_likelihoods`,
    which builds the Gaussians from them."""
    liks = tuple(likelihoods)
    if not liks or not all(isinstance(x, Likelihood) for x in liks):
        got = ", ".join(sorted({type(x).__name__ for x in liks})) or "nothing"
        raise TypeError(f"{where}: give one Likelihood per camera (e.g. gaussian_likelihoods(mus, vars) "
                        f"for the Gaussian arrays), got {got}")
    c = liks[0].n_classes
    for i, lik in enumerate(liks):
        if "V" not in lik.sizes():
            raise ValueError(f"{where}: camera {i}'s likelihood has no position axis (give the camera's, not lik.at(v))")
        if lik.n_classes != c:
            raise ValueError(f"{where}: camera {i} has C = {lik.n_classes}, camera 0 has C = {c}")
    return liks


def camera_log_likelihoods(
    gs: tuple[Float[ArrayLike, " _K"], ...],
    config: Int[ArrayLike, " n"] | tuple[int, ...],
    likelihoods,
) -> tuple[Float[Array, "C _L"], ...]:
    """Per-camera log p(g_i | c, k_i, v_i) at configuration ``config = (v_0, v_1, ...)``.

    The joint log-likelihood of a state is the sum of these over cameras
    (eq. 4.17); :func:`jaxrecog.kernels.update` consumes the tuple directly.
    ``likelihoods``: one :class:`Likelihood` per camera.  ``config`` may be a
    traced integer array (no recompilation per position).
    """
    liks = as_likelihoods(likelihoods, where="camera_log_likelihoods")
    if len(gs) != len(liks):
        raise ValueError(f"camera_log_likelihoods: {len(gs)} feature vectors for {len(liks)} cameras")
    return tuple(lik.at(config[i]).log_density(g) for i, (lik, g) in enumerate(zip(liks, gs)))
