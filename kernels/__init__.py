"""Pure JAX estimation kernels (likelihood, belief, mutual information, Fisher /
Cramér-Rao), each with a plain NumPy reference in :mod:`jaxrecog.kernels.reference`.

Nothing here imports from ``jaxrecog`` proper or ``jaxrecog.hardware``.
Per-camera arrays come as tuples (``mus = (mu_0, mu_1, ...)``, ``mu_i [V_i, C, L_i, K_i]``);
configurations are the row-major product of the cameras' positions.
"""

from .belief import (
    Belief,
    UpdateInfo,
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
from .fisher import DEFAULT_SIGMA_S, FisherDraws, crlb_criterion, fisher_draws, fisher_information
from .likelihood import camera_log_likelihoods, log_likelihood, log_likelihood_full
from .mutual_information import MITables, mi_tables, mutual_information, samples_per_configuration

__all__ = [
    "Belief",
    "DEFAULT_SIGMA_S",
    "FisherDraws",
    "MITables",
    "UpdateInfo",
    "camera_log_likelihoods",
    "class_marginal",
    "crlb_criterion",
    "entropy",
    "fisher_draws",
    "fisher_information",
    "joint",
    "level_marginal",
    "log_joint",
    "log_likelihood",
    "log_likelihood_full",
    "mi_tables",
    "mutual_information",
    "object_marginal",
    "object_pose_marginal",
    "pose_marginal",
    "samples_per_configuration",
    "transition",
    "transition_per_position",
    "uniform_belief",
    "update",
    "update_with_info",
]
