"""``mi-class-pairwise-stable`` on the belief's live classes: the default
planner for models with many classes.

The stable planner (:class:`~jaxrecog.planners.StableViewMIPlanner`) holds
divergence tables ``[V_i, C, L_i, C', L_i']``: on the thesis layout (32 and 7
positions, 6 levels) 5.7 GB and 63 ms a step at C = 512 classes, 20 GB at
1024, and a belief on two classes costs more than a uniform one.
:class:`PrunedStableViewMIPlanner` scores the same

    score(a) = I_D^tau(c; g | a) - stability * sum_i E_{c ~ P(c)} d_i[v_i, c]

with the pairwise term over the live classes of the tempered belief
(:mod:`~jaxrecog.kernels.pruned_mi`: the top-B classes holding all but
``mass`` of it, B from fixed buckets, their divergences computed in the
step; within :func:`~jaxrecog.kernels.pruning_bound` of the full sum) and the
instability term over every class (exact: ``[V_i, C]`` per camera).  It holds
the model's likelihoods and, up to
:data:`~jaxrecog.kernels.pruned_mi.UNIFORM_TABLE_MAX` classes, the first
step's belief-free values: memory linear in C.

Option ``prune`` of the registry entry: ``"auto"`` (default) this planner
from :data:`PRUNE_MIN_CLASSES` classes on and the table planner below (the
thesis's and the campaigns' models: unchanged, bit for bit); ``True`` this
planner at the default mass; a number, this planner with that mass; ``False``
the table planner.
"""

from __future__ import annotations

import math

import equinox as eqx
from jaxtyping import Array, Float

from . import kernels as K
from .kernels import pruned_mi as _pruned
from .kernels import tempered_mi as _tempered_mi
from .planner_base import Planner, stability_weight

__all__ = ["PrunedStableViewMIPlanner", "PRUNE_MIN_CLASSES", "prune_mass", "PRUNING_MARKDOWN"]

#: From this many classes on ``mi-class-pairwise-stable`` scores the live
#: classes alone (``prune="auto"``): its tables would hold 1.2 GB per
#: divergence array on the thesis layout, a step would take ~20-60 ms.
PRUNE_MIN_CLASSES = 256


#: The section of docs/planners.md on the pruned planner (appended by
#: :func:`jaxrecog.planners.planners_markdown`).
PRUNING_MARKDOWN = f"""## Many classes: the live classes alone

`mi-class-pairwise-stable` on its tables holds the divergences of every class
pair, `[V_i, C, L_i, C, L_i]` per camera: memory and time grow with C^2 (thesis
layout, C = 512: 5.7 GB and 63 ms a step), and a belief on two classes costs as
much as a uniform one.  From {PRUNE_MIN_CLASSES} classes on (option `prune`:
`"auto"`, the default; `true` / a mass in [0, 1) forces it, `false` keeps the
tables) it scores the same `I_D(c; g | a) - stability * E_P[d]` with the
pairwise term over the *live* classes (`jaxrecog/pruned_planner.py`,
`kernels/pruned_mi.py`):

- the live set is the B classes of largest mass, B the smallest bucket of
  (8, 32) (capped at C) whose classes hold at least `1 - mass` of the belief
  (default mass 1e-3); each bucket is one branch of one compiled program
  (static shapes, no recompiles); a belief wider than 32 classes is scored on
  its top 32;
- the live classes' means and variances are gathered and their B x B
  divergences computed in the step; the pairwise estimator then runs on them
  under the renormalised belief `Q = P / (1 - eps)`, eps the pruned mass;
- the instability term uses the whole belief (exact, `[V_i, C]`);
- the first step's belief (uniform over the classes and the level rows) reads
  a belief-free table built once per model (up to 1024 classes; its build
  holds `[C, V_i L_i, C]` rows); above that the first step is pruned too.

The planner holds the model's likelihoods, the instabilities and that table:
memory linear in C (C = 4000 on the thesis layout: `benchmarks/bench_scale.py`).
Below {PRUNE_MIN_CLASSES} classes (the thesis's and the campaigns' models)
nothing changes: the table planner, bit for bit.

**Bound.**  On the states `s = (c, k)` the estimator is
`I_D(s) = -sum_s P(s) log Z_P(s)`, `Z_P(s) = sum_s' P(s') Y(s, s')`,
`Y = exp(-D)` in [0, 1], `Y(s, s) = 1`.  With `P = (1 - eps) Q + eps R`
(R: the pruned classes, normalised), L = prod_i L_i level states per class:
`Z_P >= (1 - eps) Z_Q` on the live states and `>= eps Z_R` on the pruned ones
gives `I_D,P <= H_b(eps) + (1 - eps) I_D,Q + eps I_D,R`; `Z_P <= (1 - eps) Z_Q + eps`
and `Z_Q(s) >= Q(c) P(k | c)` give `I_D,P >= (1 - eps) (I_D,Q - G)` with
`G = sum_(c live) Q(c) log(1 - eps + eps L / Q(c))` (Jensen over k).  The class
target adds `sum_c P(c) T(c)`, `T(c)` in `[-log L, 0]`, and `I_D(c) <= H(c)`, so
for every configuration

`-(eps log B + eps log L + (1 - eps) G) <= I_D,P(c; g) - I_D,Q(c; g) <= H_b(eps) + eps log(C - B) + eps log L`

(state target: `eps log(B L)` and `eps log((C - B) L)` instead), computed by
`jaxrecog.kernels.pruning_bound`.  It is a worst case over the divergences
(pruned classes that coincide with live states); `tests/test_pruned_mi.py`
checks it against the unpruned kernel on random beliefs and on such a model.

**Cost.**  The live tables take ~(B L)^2 V K operations a step: B = 32 costs
16x the work of B = 8, B = 128 would cost seconds on the CPU (hence the buckets stop at
32).  `benchmarks/bench_scale.py` (thesis layout, one run on a shared, loaded
2-core machine, medians): at C = 512 the first step takes 0.33 ms against
1.7 s on the tables, a belief on two classes 36 ms against 3.0 s, a
Dirichlet(0.05) belief (top 32 classes) 1.3 s against 2.8 s; peak RSS 0.84
against 5.1 GB; C = 4000: 0.57 GB, 36 ms on two classes.  Argmax regret
against the tables at C = 32, 128, 512: at most 1.6e-4 nats.
"""


def prune_mass(prune, n_classes: int) -> float | None:
    """The belief mass the live set may leave out for option ``prune``
    (module docstring), ``None`` for the table planner; a ``ValueError`` for
    anything but ``"auto"``, a bool or a number in [0, 1)."""
    if prune == "auto":
        return _pruned.DEFAULT_PRUNE_MASS if n_classes >= PRUNE_MIN_CLASSES else None
    if isinstance(prune, bool):
        return _pruned.DEFAULT_PRUNE_MASS if prune else None
    if isinstance(prune, (int, float)) and 0.0 <= prune < 1.0:
        return float(prune)
    raise ValueError(f"prune must be 'auto', true, false or the belief mass to leave out, in [0, 1); got {prune!r}")


class PrunedStableViewMIPlanner(Planner):
    """The stable planner's score with the pairwise MI over the live classes
    (module docstring).  ``temper`` and ``stability`` as
    :class:`~jaxrecog.planners.StableViewMIPlanner`; ``mass`` the belief mass
    the live set may leave out; ``buckets`` its sizes (one compiled branch each)."""

    tables: K.PrunedTables
    instability: tuple[Float[Array, "_V C"], ...]
    target: str = eqx.field(static=True, default="class")
    divergence: str = eqx.field(static=True, default="bhattacharyya")
    temper: float = eqx.field(static=True, default=1.0)
    stability: float = eqx.field(static=True, default=1.0)
    mass: float = eqx.field(static=True, default=_pruned.DEFAULT_PRUNE_MASS)
    buckets: tuple[int, ...] = eqx.field(static=True, default=_pruned.PRUNE_BUCKETS)

    @classmethod
    def from_model(cls, model, *, target: str = "class", divergence: str = "bhattacharyya", temper: float = 1.0,
                   stability: float | None = None, mass: float = _pruned.DEFAULT_PRUNE_MASS,
                   buckets: tuple[int, ...] = _pruned.PRUNE_BUCKETS,
                   uniform_table: bool | None = None) -> "PrunedStableViewMIPlanner":
        """The likelihoods, the instabilities and (``uniform_table``, default up
        to ``UNIFORM_TABLE_MAX`` classes) the first step's belief-free values."""
        if target not in ("state", "class"):
            raise ValueError(f"target must be 'state' or 'class', got {target!r}")
        stability = stability_weight(model, stability)
        temper = _tempered_mi.check_temper(temper)
        mass = _pruned.check_mass(mass)
        _pruned.live_buckets(model.likelihoods[0].n_classes, buckets)  # checks them
        tables = K.pruned_tables(model.likelihoods, kind=divergence, uniform=uniform_table)
        inst = tuple(K.view_stability.view_instability(lik) for lik in model.likelihoods)
        return cls(math.prod(model.positions), tables, inst, target, divergence, temper, stability, mass,
                   tuple(int(b) for b in buckets))

    def scores(self, prior, key):
        del key  # deterministic
        mi = K.pruned_pairwise_mutual_information(self.tables, _tempered_mi.tempered_belief(prior, self.temper),
                                                  kind=self.divergence, target=self.target, mass=self.mass,
                                                  buckets=self.buckets)
        if self.stability == 0.0:
            return mi
        return mi - self.stability * K.view_stability.expected_instability(self.instability, prior.log_pc)
