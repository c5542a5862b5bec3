"""Pure JAX estimation kernels (likelihood, belief, mutual information, Fisher /
Cramér-Rao, pairwise-distance MI, two-step lookahead), each with a plain NumPy reference in ``tests/oracles.py``.

Nothing here imports from ``jaxrecog`` proper or ``jaxrecog.hardware``.
Per-camera values come as tuples, one entry per camera: likelihoods
(:class:`Likelihood`, each over its ``V_i`` positions), log-likelihood arrays
``[C, L_i]``, sample tables; the planners score a :class:`PredictedBelief`
(level rows per candidate position ``[V_i, C, L_i]``), a step's update acts
on a :class:`Belief` (``[C, L_i]``); configurations are the row-major product of the
cameras' positions (:class:`ConfigGrid`, ``config_grid.py``).  Likelihood families register in :data:`LIKELIHOODS`
(importing a family's module registers it: one line below per built-in kind).
In the jaxtyping annotations a per-camera size is written with a leading ``_``
(``"_V C _L _K"``): it may differ from camera to camera, so it is not matched
across the tuple, while shared sizes such as ``C`` are.
"""

from .belief import (
    Belief,
    PredictedBelief,
    UpdateInfo,
    at_every_position,
    class_marginal,
    entropy,
    joint,
    level_marginal,
    log_joint,
    object_marginal,
    object_pose_marginal,
    pose_marginal,
    transition,
    transition_per_position,
    uniform_belief,
    update,
    update_with_info,
)
from .config_grid import ConfigGrid
from .fisher import DEFAULT_SIGMA_S, FisherDraws, crlb_criterion, fisher_draws, fisher_information
from .fisher_pairwise import PairwiseFisherTables, pairwise_fisher_information, pairwise_fisher_tables
from .fisher_qmc import QMCFisherTables, qmc_fisher_draws, qmc_fisher_information, qmc_fisher_tables
from .gaussian_diag import DiagonalGaussian, log_likelihood
from .gaussian_full import FullGaussian, log_likelihood_full
from .gaussian_lowrank import LowRankGaussian
from .likelihood import (
    LIKELIHOODS,
    Likelihood,
    as_likelihoods,
    DEFAULT_LIKELIHOOD,
    DEFAULT_VIEW_JITTER_LIKELIHOOD,
    camera_log_likelihoods,
    gaussian,
    gaussian_likelihoods,
    likelihood_class,
    likelihood_names,
    register_likelihood,
)
from .lookahead import LookaheadDraws, lookahead_draws, lookahead_information, outcome_strata
from .mutual_information import MITables, mi_tables, mutual_information, samples_per_configuration
from .pairwise_mi import DIVERGENCES, PairwiseTables, pairwise_mutual_information, pairwise_tables
from .pruned_mi import PrunedTables, pruned_pairwise_mutual_information, pruned_tables, pruning_bound
from . import adaptive_scale, pruned_mi, shared_latent, view_stability
from .student_t import StudentT
from .view_mixture import LowRankViewMixture, ViewMixture

__all__ = [
    "Belief",
    "ConfigGrid",
    "DEFAULT_LIKELIHOOD",
    "DEFAULT_VIEW_JITTER_LIKELIHOOD",
    "DEFAULT_SIGMA_S",
    "DIVERGENCES",
    "DiagonalGaussian",
    "FisherDraws",
    "FullGaussian",
    "LIKELIHOODS",
    "Likelihood",
    "LookaheadDraws",
    "LowRankGaussian",
    "LowRankViewMixture",
    "MITables",
    "PairwiseTables",
    "PairwiseFisherTables",
    "PredictedBelief",
    "QMCFisherTables",
    "UpdateInfo",
    "ViewMixture",
    "shared_latent",
    "as_likelihoods",
    "at_every_position",
    "camera_log_likelihoods",
    "class_marginal",
    "crlb_criterion",
    "entropy",
    "fisher_draws",
    "fisher_information",
    "gaussian",
    "gaussian_likelihoods",
    "joint",
    "level_marginal",
    "likelihood_class",
    "likelihood_names",
    "log_joint",
    "log_likelihood",
    "log_likelihood_full",
    "lookahead_draws",
    "lookahead_information",
    "mi_tables",
    "mutual_information",
    "object_marginal",
    "object_pose_marginal",
    "outcome_strata",
    "pairwise_fisher_information",
    "pairwise_fisher_tables",
    "pairwise_mutual_information",
    "pairwise_tables",
    "pose_marginal",
    "PrunedTables",
    "pruned_pairwise_mutual_information",
    "pruned_tables",
    "pruning_bound",
    "qmc_fisher_draws",
    "qmc_fisher_information",
    "qmc_fisher_tables",
    "register_likelihood",
    "StudentT",
    "samples_per_configuration",
    "transition",
    "transition_per_position",
    "uniform_belief",
    "update",
    "update_with_info",
]
