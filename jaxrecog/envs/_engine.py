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
- :func:`uniform_prior` / :func:`observe` / :func:`class_belief`: the
  recognizer's own initial belief, Bayes update from images (eq. 3.1,
  4.17-4.19) and belief over (class, levels)
  (:func:`jaxrecog.recognizer.update_from_images`: with its shared view
  component and adaptive scale where the env's settings ask for them);
- :func:`belief_from_features` / :func:`belief_from_logliks`: the plain
  update from eigenspace features or their log-likelihoods (the functional
  env's precomputed tables);
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
from ..hardware.rigs.rig import CaptureJob
from ..hardware.rigs.rig_pool import run_job
from ..recognizer import initial_belief, update_from_images, view_marginal

__all__ = ["check_layout", "start", "capture", "observe", "class_belief", "belief_from_features", "belief_from_logliks",
           "log_likelihoods", "move_prior", "uniform_prior", "FEATURE_BOUND"]

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
    takes it (:func:`~jaxrecog.hardware.rigs.rig_pool.run_job`, the one place the
    order of a capture's rig calls is written): the capture noise reseeded
    with ``noise_seed`` (the driver's ``(seed, trial, step)``), the cameras
    moved, one ``Rig.capture``.

    Returns ``(images uint8 [n, H, W], true occluded fraction float64 [n])``;
    the fractions are empty (shape ``(0,)``) where the rig does not know them
    (stored or real images), as in :class:`~jaxrecog.hardware.Capture`.
    """
    cap = run_job(rig, CaptureJob(0, None, noise_seed, tuple(int(v) for v in config)))
    return np.asarray(cap.images, np.uint8), np.asarray(cap.occluded, np.float64)


def uniform_prior(model, shared_view: bool = False) -> K.Belief:
    """The recognizer's initial belief (section 3.3; over the ``C * M``
    extended classes with ``shared_view``): :func:`jaxrecog.recognizer.initial_belief`."""
    return initial_belief(model, shared_view)


def class_belief(model, belief: K.Belief | K.PredictedBelief, shared_view: bool = False
                 ) -> K.Belief | K.PredictedBelief:
    """The belief over (class, levels) of an env belief (its marginal over
    the view component with ``shared_view``), of the same form."""
    return view_marginal(model, belief, shared_view)


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
def observe(model, prior: K.Belief, config: Int[ArrayLike, " n"], images: Real[ArrayLike, "n H W"], *,
            shared_view: bool = False, adaptive_scale: float = 1.0):
    """Features g_i = V_iᵀ(y_i/‖y_i‖ − x̄_i) (eq. 4.1-4.11) and the Bayes update
    as the recognizer's step makes it (:func:`jaxrecog.recognizer.update_from_images`):
    ``(posterior, features, ok)``.  An unusable image (black, constant, not
    finite) leaves the belief unchanged and sets ``ok = False``."""
    posterior, gs, ok, _ = update_from_images(model, prior, config, images, shared_view=shared_view,
                                              adaptive_scale=adaptive_scale)
    return posterior, gs, ok


def move_prior(posterior: K.Belief, config: Int[ArrayLike, " n"], next_config: Int[ArrayLike, " n"],
               kind: str = "uniform", rho: float = 0.9) -> K.Belief:
    """The prior of the images at ``next_config``: cameras that move get the
    level transition, cameras that stay keep their levels (eq. 3.7-3.9)."""
    moved = jnp.asarray(next_config) != jnp.asarray(config)
    return K.transition(posterior, moved, kind=kind, rho=rho)
