"""The environments' one contact with the rig and the recognizer's belief.

Everything :mod:`jaxrecog.envs` needs from the ``Rig`` protocol and from the
recognizer's belief arithmetic lives in this file, so a change of either API
is adapted here only:

- :func:`check_layout`: the model and the rig agree on cameras, positions,
  objects and poses (where the rig knows them) and image shape
  (:func:`jaxrecog.counts.check_counts`, the one such check);
- :func:`start` / :func:`capture`: a scene set up once per episode, then one
  image set per step with the true occluded fractions, exactly as the trial
  driver takes them (``reset`` the scene; ``reseed`` the capture noise,
  ``move``, ``capture``);
- :func:`observe` / :func:`belief_from_features` / :func:`belief_from_logliks`:
  the recognizer's Bayes update (eq. 3.1, 4.17-4.19) from images, from
  eigenspace features or from their log-likelihoods;
- :func:`move_prior`: the level transition for the cameras that move
  (eq. 3.7-3.9).
"""

from __future__ import annotations

from typing import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from .. import kernels as K
from ..counts import check_counts
from ..driver import TrialSpec
from ..recognizer import image_features

__all__ = ["check_layout", "start", "capture", "observe", "belief_from_features", "belief_from_logliks", "log_likelihoods", "move_prior", "uniform_prior", "FEATURE_BOUND"]

#: |g_k| <= ||y_hat - x_bar|| <= sqrt(2): unit-energy images with non-negative
#: pixels and a mean of such images (eq. 4.1-4.11); an unusable image gives 0.
FEATURE_BOUND = 2.0


def check_layout(model, rig) -> None:
    """A clear one-line ``ValueError`` (:class:`~jaxrecog.counts.CountsMismatchError`)
    when the rig cannot serve the model: cameras and positions per camera,
    objects and poses (where the rig knows them), image shape."""
    check_counts(model, rig, other_name=f"rig {type(rig).__name__}")


def start(rig, scene: TrialSpec) -> None:
    """Set ``scene`` up on the rig (object, pose, occluders), once per episode
    as the trial driver does (:mod:`jaxrecog.driver`)."""
    rig.reset(scene.object, scene.pose, scene.occluders)


def capture(rig, config: Sequence[int] | np.ndarray, noise_seed) -> tuple[np.ndarray, np.ndarray]:
    """One image set at ``config``, taken as :func:`jaxrecog.driver.run_trials`
    takes it: the capture noise reseeded with ``noise_seed`` (the driver's
    ``(seed, trial, step)``), the cameras moved, one ``Rig.capture``.

    Returns ``(images uint8 [n, H, W], true occluded fraction float64 [n])``;
    the fractions are empty (shape ``(0,)``) where the rig does not know them
    (stored or real images), as in :class:`~jaxrecog.hardware.Capture`.
    """
    rig.reseed(noise_seed)
    rig.move(tuple(int(v) for v in config))
    cap = rig.capture()
    return np.asarray(cap.images, np.uint8), np.asarray(cap.occluded, np.float64)


def uniform_prior(model) -> K.Belief:
    """The uniform belief of section 3.3 over the model's classes and levels."""
    dtype = model.cameras[0].likelihood.dtype
    return K.uniform_belief(model.n_classes, tuple(model.n_levels for _ in model.cameras), dtype=dtype)


def log_likelihoods(model, config: Int[ArrayLike, " n"],
                    features: tuple[Float[Array, " _K"], ...]) -> tuple[Float[Array, "C _L"], ...]:
    """log p(g_i | c, k_i, v_i) per camera at ``config`` (eq. 4.17-4.22), from the model."""
    return K.camera_log_likelihoods(features, config, model.likelihoods)


def belief_from_logliks(prior: K.Belief, logliks: tuple[Float[Array, "C _L"], ...],
                        valid: Bool[ArrayLike, ""] | bool = True) -> tuple[K.Belief, Bool[Array, ""]]:
    """Bayes update of the factorised belief (eq. 3.1): ``(posterior, ok)``;
    ``ok`` is false (and the belief unchanged) when ``valid`` is false or the
    evidence is unusable."""
    posterior, info = K.update_with_info(prior, logliks, valid=valid)
    return posterior, info.ok


def belief_from_features(model, prior: K.Belief, config: Int[ArrayLike, " n"],
                         features: tuple[Float[Array, " _K"], ...],
                         valid: Bool[ArrayLike, ""] | bool = True) -> tuple[K.Belief, Bool[Array, ""]]:
    """The Bayes update with the features' log-likelihoods (eq. 3.1, 4.17)."""
    return belief_from_logliks(prior, log_likelihoods(model, config, features), valid)


@eqx.filter_jit
def observe(model, prior: K.Belief, config: Int[ArrayLike, " n"], images: Real[ArrayLike, "n H W"]):
    """Features g_i = V_iᵀ(y_i/‖y_i‖ − x̄_i) (eq. 4.1-4.11) and the Bayes update:
    ``(posterior, features, ok)``.  An unusable image (black, constant, not
    finite) leaves the belief unchanged and sets ``ok = False``."""
    gs, usable = image_features(model, config, jnp.asarray(images))
    posterior, ok = belief_from_features(model, prior, config, gs, usable)
    return posterior, gs, ok


def move_prior(posterior: K.Belief, config: Int[ArrayLike, " n"], next_config: Int[ArrayLike, " n"],
               kind: str = "uniform", rho: float = 0.9) -> K.Belief:
    """The prior of the images at ``next_config``: cameras that move get the
    level transition, cameras that stay keep their levels (eq. 3.7-3.9)."""
    moved = jnp.asarray(next_config) != jnp.asarray(config)
    return K.transition(posterior, moved, kind=kind, rho=rho)
