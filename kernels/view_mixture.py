"""A sensor model that knows the views between its training views: a mixture
with one component per *rendered view* of a class near the training view.

    p(g | c, k, v) = sum_m w[v, c, k, m] p_m(g | c, k, v)

``p_m`` is a family of its own (``component``): the thesis's diagonal
Gaussian (``view-mixture``) or the low-rank-plus-diagonal Gaussian
(``view-mixture-lowrank``).  A mixture stores its component family's fields
with an ``M`` axis after ``L`` (``mu [V, C, L, M, K]``, ...) plus ``log_w
[V, C, L, M]``; every method reads the components as one set of the component
family over ``L * M`` "levels" (:meth:`_ViewMixture.components`).

Component ``m = 0`` is fitted to the augmented samples of the training image
itself (exactly the thesis's diagonal Gaussian, eq. 4.23-4.24); components
``m = 1 .. M-1`` to those of the database's ``jitter`` images of the same
view: the object turned a few degrees off the training pose
(``train_model(view_jitter=True)``).  Why a mixture and not one Gaussian
over all of them (``gaussian-diag`` with view jitter, which pools the jitter
samples into one component): pooling makes every component broad in the
directions the sticker of a look-alike moves, so a sticker object's model
learns "sticker or not" and the plain object's on-grid capture fits it
(docs/results.md, "Training against confident errors"); the mixture keeps
each rendered view sharp, so an on-grid capture is still explained best by
its own component, while a capture a few degrees off the grid finds the
component rendered nearest to it instead of being far from everything.

    log p = logsumexp_m [log w_m + log p_m(g | c, k, v)]

Occluded jitter components (``occluded_jitter``).  Augmenting every jitter
image at every occlusion level costs ``M`` times the thesis model's training
(the occluded samples are projected pixel by pixel).  With
``occluded_jitter="translated"`` training augments the jitter images at level
0 only, and the occluded components of a jitter view are the training view's
component of that level, moved by the jitter view's level-0 offset::

    mu[c, k, m]    = mu[c, k, 0] + (mu[c, 0, m] - mu[c, 0, 0])     (k >= 1, m >= 1)
    Sigma[c, k, m] = Sigma[c, k, 0]

(an occluder changes a turned view as it changes the training view).  This
is the default (:data:`DEFAULT_OCCLUDED_JITTER`): on the occluded campaigns
it is as accurate as ``"sampled"``, which fits every component to its own
samples, and trains ~5x faster.

Draws use one more normal number than the component family: ``z[0]`` picks
the component by inverse CDF of the weights (``u = Phi(z[0])``), ``z[1:]``
draws from it.  Moments are the mixture's (mean ``sum w mu_m``, covariance
``sum w (Sigma_m + (mu_m - mean)(mu_m - mean)^T)``, a form without the
cancellation of ``E[g g^T] - mean mean^T`` in float32).

Pairwise divergence (the ``mi-*-pairwise`` and ``crlb-pairwise`` planners).
There is no closed form between mixtures.  :meth:`ViewMixture.bhattacharyya`
is a bound, from ``sqrt(sum_i a_i) <= sum_i sqrt(a_i)``::

    BC(p, q) = int sqrt(sum_m w_m p_m  sum_n w'_n q_n)
            <= sum_{m,n} sqrt(w_m w'_n) BC(p_m, q_n)
    D(p, q)  >= -log sum_{m,n} sqrt(w_m w'_n) exp(-D_B(p_m, q_n))   (what it returns)

a lower bound on the Bhattacharyya distance, exact for one component and for
components far apart.  It is *not* what the planners use
(:meth:`divergence`): a view mixture's components are views a few degrees
apart, so they overlap, the cross terms add up and the sum exceeds 1: the
bound is <= 0 between a mixture and itself and collapses to <= 0 between a
look-alike pair at the one view that tells them apart (the pairwise MI of
that view then reads 0, and the planner walks the positions in index order
instead of taking it).  :meth:`divergence` is therefore the divergence
between the mixtures' moment-matched Gaussians (mean and covariance below),
for both kinds: not a bound (Kolchinsky & Tracey's estimator bounds I only
with the exact divergences), but it orders the views by how far apart the
classes' appearance distributions lie, and it is exact for one component.
On the synthetic rig's jitter case this took the recipe from 94.00 to
95.25 % (800 trials; docs/results.md, "Version 6"); on the real photos the
classes lie far apart and the choices do not change.
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax
import jax.numpy as jnp
import jax.scipy.special as jsp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._grid import lse
from .gaussian_diag import DiagonalGaussian
from .gaussian_lowrank import LowRankGaussian, whiten
from .likelihood import Likelihood, register_likelihood

__all__ = ["ViewMixture", "LowRankViewMixture", "mixture_log_weights"]


def mixture_log_weights(n_components: int, nominal_weight: float | None = None) -> np.ndarray:
    """``log w [M]``: uniform (``nominal_weight=None``), or ``w_0 = nominal_weight``
    for the training view and the rest shared equally by the ``M - 1`` others."""
    m = int(n_components)
    if m < 1:
        raise ValueError(f"view-mixture: need at least one component, got {m}")
    if nominal_weight is None:
        return np.full(m, -math.log(m))
    w0 = float(nominal_weight)
    if not (0.0 < w0 <= 1.0) or (m == 1 and w0 != 1.0) or (m > 1 and w0 == 1.0):
        raise ValueError(f"view-mixture: nominal_weight must be in (0, 1) with {m} components "
                         f"(1 with one), got {nominal_weight}")
    if m == 1:
        return np.zeros(1)
    return np.log(np.r_[w0, np.full(m - 1, (1.0 - w0) / (m - 1))])


OCCLUDED_JITTER = ("sampled", "translated")
#: The default of ``occluded_jitter`` (module docstring): as accurate as
#: ``"sampled"`` on the occluded campaigns and ~5x cheaper to train
#: (docs/results.md, "View mixtures").
DEFAULT_OCCLUDED_JITTER = "translated"


def _check_occluded_jitter(value) -> None:
    if value not in OCCLUDED_JITTER:
        raise ValueError(f"view-mixture: occluded_jitter must be one of {', '.join(OCCLUDED_JITTER)}, got {value!r}")


class _ViewMixture(Likelihood):
    """A mixture of ``M`` components of the family ``component`` per class ``c``
    and level ``k`` (module docstring).  Subclasses name ``component`` and
    declare its fields with the extra ``M`` axis, plus ``log_w [V, C, L, M]``."""

    component: ClassVar[type[Likelihood]]
    view_components: ClassVar[bool] = True

    @classmethod
    def _component_fields(cls) -> tuple[str, ...]:
        """The component family's stored fields, then its derived ones (not stored)."""
        return tuple(cls.component.field_shapes) + tuple(cls.component.derived_shapes)

    @property
    def n_components(self) -> int:
        return self.sizes()["M"]

    @property
    def noise_dim(self) -> int:
        """One normal number picks the component, the rest draw from it."""
        return self.components().noise_dim + 1

    def components(self) -> Likelihood:
        """The ``[C, L, M]`` components of one position as one ``component`` set
        over ``L * M`` levels (index ``k * M + m``)."""
        lead = np.ndim(self.log_w) - 2
        return self.component(**{f: _merge(getattr(self, f), lead) for f in self._component_fields()})

    def _from_components(self, flat: Likelihood, log_w) -> "_ViewMixture":
        lead, m = np.ndim(log_w) - 2, np.shape(log_w)[-1]
        return type(self)(**{f: _split(getattr(flat, f), lead, m) for f in self._component_fields()}, log_w=log_w)

    def component_log_density(self, g: Float[ArrayLike, "*B K"]) -> Float[Array, "*B C L M"]:
        """``log w_m + log p_m(g | c, k)`` for every component."""
        c, l, m = self.log_w.shape
        ld = self.components().log_density(g)                                 # [*B, C, L*M]
        return ld.reshape(ld.shape[:-1] + (l, m)) + self.log_w.reshape((1,) * (g.ndim - 1) + (c, l, m))

    def log_density(self, g: Float[ArrayLike, "*B K"]) -> Float[Array, "*B C L"]:
        """``logsumexp_m [log w_m + log p_m(g | c, k)]`` (module docstring)."""
        return lse(self.component_log_density(g), axis=-1)

    def sample(self, z: Float[ArrayLike, "C L J Z"]) -> Float[Array, "C L J K"]:
        """Component ``m = #{cumulative weights < Phi(z[0])}``, then its draw from ``z[1:]``."""
        c, l, m = self.log_w.shape
        u = jsp.ndtr(z[..., 0])                                               # [C, L, J]
        cum = jnp.cumsum(jnp.exp(self.log_w), axis=-1)[..., :-1]              # [C, L, M-1]
        pick = jnp.sum(u[..., None] > cum[:, :, None, :], axis=-1)            # [C, L, J]
        zz = jnp.repeat(z[..., 1:], m, axis=1)                                # [C, L*M, J, Z-1]
        g = self.components().sample(zz)                                      # [C, L*M, J, K]
        g = g.reshape((c, l, m) + g.shape[2:])
        return jnp.take_along_axis(g, pick[:, :, None, :, None], axis=2)[:, :, 0]

    def _weights(self):
        return jnp.exp(self.log_w)                                            # [C, L, M]

    def _component_moments(self):
        c, l, m = self.log_w.shape
        flat = self.components()
        mu = flat.mean().reshape(c, l, m, -1)
        return mu, flat, (c, l, m)

    def mean(self) -> Float[Array, "C L K"]:
        mu, _, _ = self._component_moments()
        return jnp.einsum("clm,clmk->clk", self._weights(), mu)

    def covariance(self) -> Float[Array, "C L K K"]:
        mu, flat, (c, l, m) = self._component_moments()
        w = self._weights()
        cov = flat.covariance().reshape(c, l, m, mu.shape[-1], mu.shape[-1])
        d = mu - jnp.einsum("clm,clmk->clk", w, mu)[:, :, None, :]           # about the mixture mean:
        return jnp.einsum("clm,clmkj->clkj", w, cov + d[..., :, None] * d[..., None, :])  # no cancellation

    def variance(self) -> Float[Array, "C L K"]:
        mu, flat, (c, l, m) = self._component_moments()
        w = self._weights()
        var = flat.variance().reshape(c, l, m, -1)
        d = mu - jnp.einsum("clm,clmk->clk", w, mu)[:, :, None, :]
        return jnp.einsum("clm,clmk->clk", w, var + d * d)

    def scaled(self, factor: Float[ArrayLike, " L"]) -> "_ViewMixture":
        """Every component of level k with its covariance times ``factor[k]`` (the weights stay)."""
        m = self.log_w.shape[-1]
        return self._from_components(self.components().scaled(jnp.repeat(factor, m)), self.log_w)

    def scaling_terms(self, g: Float[ArrayLike, "N K"]):
        """The component family's terms of ``g`` over the ``L * M`` components
        (for the Gaussians ``q`` and ``log|2 pi Sigma|``), computed once."""
        return self.components().scaling_terms(g)

    def scaled_log_density(self, terms, log_factor: Float[Array, " L"]) -> Float[Array, "N C L"]:
        """``scaled(exp(log_factor)).log_density(g)`` from :meth:`scaling_terms`:
        the component family's scaled density with each level's factor on all
        its ``M`` components, then ``logsumexp_m (log w_m + ...)``."""
        c, l, m = self.log_w.shape
        ld = self.components().scaled_log_density(terms, jnp.repeat(log_factor, m))      # [N, C, L*M]
        # calibration differentiates this: jax.nn.logsumexp's own derivative (``_grid.lse``'s
        # gradient came out NaN inside the vmapped L-BFGS under XLA's -O0 test flags)
        return jax.nn.logsumexp(ld.reshape(ld.shape[:-1] + (l, m)) + self.log_w[None], axis=-1)

    def divergence(self, kind: str) -> Float[Array, "C L C L"]:
        """The planners' divergence: that of the moment-matched Gaussians,
        for both kinds (module docstring: the mixture bound :meth:`bhattacharyya`
        collapses when the views overlap)."""
        return self.moment_matched_divergence(kind)

    def bhattacharyya(self) -> Float[Array, "C L C L"]:
        """The lower bound ``-log sum_{m,n} sqrt(w_m w'_n) exp(-D_B(p_m, q_n))``
        (module docstring), from the component family's closed form per pair;
        not the planners' divergence (:meth:`divergence`)."""
        c, l, m = self.log_w.shape
        d = self.components().bhattacharyya().reshape(c, l, m, c, l, m)
        half = 0.5 * self.log_w
        x = half[:, :, :, None, None, None] + half[None, None, None] - d
        return -lse(lse(x, axis=-1), axis=2)

    def problems(self) -> list[tuple[str, str]]:
        lead = np.ndim(self.log_w) - 2
        flat = self.component(**{f: _merge(np.asarray(getattr(self, f)), lead) for f in self.component.field_shapes})
        out = list(flat.problems())
        total = np.logaddexp.reduce(np.asarray(self.log_w, np.float64), axis=-1)
        if np.any(np.abs(total) > 1e-3):
            out.append(("log_w", "has mixture weights that do not sum to 1"))
        return out

    @classmethod
    def with_defaults(cls, **options) -> dict:
        """``occluded_jitter`` is recorded even when not given: its default
        became ``"translated"`` after mixtures had been trained ``"sampled"``."""
        return {"occluded_jitter": DEFAULT_OCCLUDED_JITTER, **options}

    @classmethod
    def jitter_sampled(cls, level: int, *, occluded_jitter: str = DEFAULT_OCCLUDED_JITTER, **options) -> bool:
        """Whether training augments the jitter images at occlusion level
        ``level``: always at level 0; at the occluded levels only with
        ``occluded_jitter="sampled"`` (with ``"translated"`` :meth:`fit`
        derives those components, module docstring)."""
        _check_occluded_jitter(occluded_jitter)
        return level == 0 or occluded_jitter == "sampled"

    @classmethod
    def fit(cls, mean, second, floor, *, nominal_weight: float | None = None,
            occluded_jitter: str = DEFAULT_OCCLUDED_JITTER, **options) -> "_ViewMixture":
        """The component family's fit (eq. 4.23-4.24 for the Gaussians) per component.

        Args:
            mean: ``[C, L, M, K]`` sample means per component (``m = 0``: the
                training image's samples, then one per jitter image of the view).
            second: ``[C, L, M, K]`` sample variances or ``[C, L, M, K, K]``
                covariances (the component family's ``second_moments``).
            floor: ``[C, L]`` variance floor.
            nominal_weight: weight of the training view's component (default:
                all ``M`` components weigh ``1 / M``).
            occluded_jitter: ``"translated"`` (default): the jitter components
                of the occluded levels (``k >= 1, m >= 1``; their moments are
                not read and may be NaN) are the training view's component of
                that level moved by the jitter view's level-0 offset (module
                docstring); ``"sampled"``: every component from its own moments.
            **options: the component family's fit options.
        """
        _check_occluded_jitter(occluded_jitter)
        mean = np.asarray(mean, np.float64)
        if mean.ndim != 4:
            raise ValueError(f"{cls.kind}: fit needs per-component moments [C, L, M, K], got {mean.shape} "
                             f"(train with view jitter)")
        c, l, m, _ = mean.shape
        log_w = np.array(np.broadcast_to(mixture_log_weights(m, nominal_weight), (c, l, m)))
        second = np.asarray(second, np.float64)
        floor = np.asarray(floor, np.float64)
        if occluded_jitter == "sampled" or l == 1 or m == 1:
            flat = cls.component.fit(mean.reshape(c, l * m, -1), second.reshape((c, l * m) + second.shape[3:]),
                                     np.repeat(floor, m, axis=1), **options)
            return cls(**{f: _split(np.asarray(getattr(flat, f)), 1, m) for f in cls._component_fields()},
                       log_w=log_w)
        # translated: fit the L training-view components and the M - 1 level-0 jitter
        # components (the distinct covariances), then index them into [C, L, M]
        flat = cls.component.fit(np.concatenate([mean[:, :, 0], mean[:, 0, 1:]], axis=1),
                                 np.concatenate([second[:, :, 0], second[:, 0, 1:]], axis=1),
                                 np.concatenate([floor, np.repeat(floor[:, :1], m - 1, axis=1)], axis=1), **options)
        pick = np.empty((l, m), np.int64)
        pick[:, 0] = np.arange(l)                     # (k, 0): the training view's own fit
        pick[0, 1:] = l + np.arange(m - 1)            # (0, m): the jitter view's own fit
        pick[1:, 1:] = np.arange(1, l)[:, None]       # (k, m): the training view's level k ...
        fields = {f: np.take(np.asarray(getattr(flat, f)), pick, axis=1) for f in cls._component_fields()}
        fields["mu"][:, 1:, 1:] = mean[:, 1:, :1] + (mean[:, :1, 1:] - mean[:, :1, :1])  # ... moved
        return cls(**fields, log_w=log_w)


def _merge(x, lead: int):
    """``[*V, C, L, M, ...]`` -> ``[*V, C, L*M, ...]`` (``lead`` = number of axes before L)."""
    sh = tuple(x.shape)
    return x.reshape(sh[:lead] + (sh[lead] * sh[lead + 1],) + sh[lead + 2:])


def _split(x, lead: int, m: int):
    """``[*V, C, L*M, ...]`` -> ``[*V, C, L, M, ...]``."""
    sh = tuple(x.shape)
    return x.reshape(sh[:lead] + (sh[lead] // m, m) + sh[lead + 1:])


def _mixture_shapes(component: type[Likelihood]) -> dict[str, str]:
    """A mixture's ``field_shapes``: the component family's fields with ``M``
    after ``L``, then ``log_w [V, C, L, M]``."""
    return {**{f: s.replace("L", "L M", 1) for f, s in component.field_shapes.items()}, "log_w": "V C L M"}


@register_likelihood
class ViewMixture(_ViewMixture):
    """Mixture of diagonal Gaussians (:class:`~.gaussian_diag.DiagonalGaussian`).

    Attributes:
        mu: ``[V, C, L, M, K]`` component means (``m = 0``: the training view).
        var: ``[V, C, L, M, K]`` component variances, strictly positive.
        log_w: ``[V, C, L, M]`` log mixture weights (each row sums to 1).
    """

    kind: ClassVar[str] = "view-mixture"
    component: ClassVar[type[Likelihood]] = DiagonalGaussian
    field_shapes: ClassVar[dict[str, str]] = _mixture_shapes(DiagonalGaussian)
    second_moments: ClassVar[str] = DiagonalGaussian.second_moments
    fit_options: ClassVar[tuple[str, ...]] = ("nominal_weight", "occluded_jitter")

    mu: Float[ArrayLike, "*V C L M K"]
    var: Float[ArrayLike, "*V C L M K"]
    log_w: Float[ArrayLike, "*V C L M"]


@register_likelihood
class LowRankViewMixture(_ViewMixture):
    """Mixture of low-rank-plus-diagonal Gaussians (:class:`~.gaussian_lowrank.LowRankGaussian`).

    Attributes:
        mu: ``[V, C, L, M, K]``; W: ``[V, C, L, M, K, R]``; psi: ``[V, C, L, M, K]``.
        log_w: ``[V, C, L, M]`` log mixture weights (each row sums to 1).
    """

    kind: ClassVar[str] = "view-mixture-lowrank"
    component: ClassVar[type[Likelihood]] = LowRankGaussian
    field_shapes: ClassVar[dict[str, str]] = _mixture_shapes(LowRankGaussian)
    second_moments: ClassVar[str] = LowRankGaussian.second_moments
    fit_options: ClassVar[tuple[str, ...]] = ("nominal_weight", "occluded_jitter", *LowRankGaussian.fit_options)

    mu: Float[ArrayLike, "*V C L M K"]
    W: Float[ArrayLike, "*V C L M K R"]
    psi: Float[ArrayLike, "*V C L M K"]
    log_w: Float[ArrayLike, "*V C L M"]
    # the components' derived arrays (gaussian_lowrank.whiten), never stored
    whitened: Float[ArrayLike, "*V C L M R K"]
    half_logdet_capacitance: Float[ArrayLike, "*V C L M"]

    def __init__(self, mu, W, psi, log_w, whitened=None, half_logdet_capacitance=None):
        self.mu, self.W, self.psi, self.log_w = mu, W, psi, log_w
        if whitened is None or half_logdet_capacitance is None:
            whitened, half_logdet_capacitance = whiten(W, psi)
        self.whitened, self.half_logdet_capacitance = whitened, half_logdet_capacitance
