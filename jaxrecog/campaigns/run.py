"""The thesis cases' campaigns (chapter 7) on the synthetic rig: every planner
on the *same* trials (poses, initial configurations, occluder layouts and
capture noise per trial), resumable, and one traced trial (Table 7.8).

``mi`` is the thesis's target I(s; g) over the full state (object, pose and
both occlusion levels); ``mi-class`` is I(c; g) with the levels marginalised
(docs/design.md §3): with six levels per camera the state target is dominated by
the occlusion levels and can prefer views that reveal occlusion over views
that reveal identity.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import jax.random as jr

from ..campaign import TrialSpec, run_campaign
from ..motion import rig_travel_times
from ..recognizer_factory import make_recognizer
from ..results import TrialResult, summarize
from .cases import CASES, Case, case_model, case_settings, case_trials
from .naming import run_id
from .preparation import Prepared, prepare, progress_bar
from .reports import CaseReport
from .rigs import capture_pool, make_rig
from .settings import Settings
from .stores import campaign_store, model_sha256

if TYPE_CHECKING:
    from ..hardware.rigs.capture_memo import CaptureMemo

__all__ = ["campaign_recognizer", "compare_planners", "run_case", "run_trace"]


def campaign_recognizer(model, planner: str, settings: Settings, travel=None):
    """The campaign's recognizer (:func:`jaxrecog.recognizer_factory.make_recognizer`):
    the planner's tables from ``PRNGKey(settings.seed)``, the settings' recipe
    (stop rule) and run options.  ``travel``: per-camera travel-time tables of
    the rig (:func:`jaxrecog.motion.rig_travel_times`) — the motion cost
    ``settings.motion_cost`` uses them and every result records its travel
    time; ``None`` (a rig without a geometry) allows only ``motion_cost = 0``."""
    return make_recognizer(model, planner, recipe=settings.recipe, key=jr.PRNGKey(settings.seed),
                           samples=settings.samples, min_per_stratum=settings.min_per_stratum,
                           max_steps=settings.max_steps, transition=settings.transition,
                           shared_view=settings.shared_view, travel=travel, motion_cost=settings.motion_cost)


def compare_planners(
    case: Case,
    model,
    rig,  # one Rig, one per lockstep slot, or a RigPool
    specs: Sequence[TrialSpec],
    settings: Settings,
    planners: Sequence[str],
    store_name: Callable[[str], str],
    *,
    progress: bool,
    on_result: Callable[[str, TrialResult], None] | None,
    probe,
    live: Callable[[str, Any, Any], Callable] | None = None,
    content: Mapping[str, str] | None = None,
) -> CaseReport:
    """Each planner on the same trials (``specs``) on ``rig``; finished trials
    go to ``workdir/trials/<store_name(planner)>.jsonl`` (resumable; its header
    records the settings, the planner, the model's digest and ``content``,
    digests of further data the trials depend on:
    :func:`~jaxrecog.campaigns.stores.campaign_store`).
    ``probe``: a rig of the same table, whose geometry gives the travel times.
    ``live(planner, model, probe)``: the step observer of a planner's trials
    (the live view, :class:`jaxrecog.liveview.CampaignView`), or ``None``."""
    rows, results, seconds = {}, {}, {}
    travel = rig_travel_times(probe)
    content = {"model_sha256": model_sha256(model), **dict(content or {})}   # hashed once for every planner
    for planner in planners:
        rec = campaign_recognizer(model, planner, settings, travel)
        store = campaign_store(settings, store_name(planner), planner, model, content)
        t0 = time.perf_counter()
        with progress_bar(len(specs), f"{case.name} {planner}" if case.name == "dataset" else f"case {case.name} {planner}", progress) as bar:
            already = len(store.load())
            bar.update(min(already, len(specs)))
            res = run_campaign(rec, rig, specs, key=jr.PRNGKey(settings.seed + 1), batch=settings.batch, seed=settings.seed, store=store, progress=bar.update,
                               devices=settings.devices,
                               on_step=None if live is None else live(planner, model, probe))
        seconds[planner] = time.perf_counter() - t0
        results[planner] = res
        rows[planner] = summarize(res, model.n_objects)
        if on_result is not None:
            for r in res:
                on_result(planner, r)
    return CaseReport(case, settings, rows, results, seconds)


def run_case(
    name: str,
    settings: Settings,
    planners: Sequence[str] | None = None,
    *,
    progress: bool = False,
    prepared: Prepared | None = None,
    on_result: Callable[[str, TrialResult], None] | None = None,
    memo: "CaptureMemo | None" = None,
    live: Callable[[str, Any, Any], Callable] | None = None,
) -> CaseReport:
    """Run one thesis case with each planner on the same trials (resumable:
    finished trials are kept in ``workdir/trials``).  The planners share
    their captures (:class:`~jaxrecog.hardware.rigs.capture_memo.CaptureMemo`:
    a trial's first images are the same for every planner, and so is any
    later capture two planners agree on); pass ``memo`` to share them with
    other cases too (``reproduce_thesis.py --case all``: cases (ii) and
    (iii) show the same scenes).  The results are those of rendering every
    capture.  ``live``: the live view's observer factory (:func:`compare_planners`)."""
    if name not in CASES:
        raise ValueError(f"unknown case {name!r}; choose one of {', '.join(CASES)}")
    case = CASES[name]
    settings = case_settings(case, settings)
    if settings.cluster:  # a cluster that is not there: said before anything renders or trains
        from ..cluster import connect

        connect(settings.cluster)
    prepared = prepared or prepare(settings, progress=progress, databases=(case.database,))
    model = case_model(prepared, case)
    probe = make_rig(settings, case.cameras, seed=settings.seed)  # the table and geometry, here
    specs = case_trials(case, settings, probe, model.n_objects, model.n_poses)
    rid = run_id(settings, prepared.models[case.database])
    if memo is None:
        from ..hardware.rigs.capture_memo import CaptureMemo

        memo = CaptureMemo()
    with capture_pool(settings, case.cameras, seed=settings.seed, memo=memo) as rigs:
        return compare_planners(case, model, rigs, specs, settings, list(planners or case.planners),
                                lambda planner: f"case-{name}-{planner}-{rid}", progress=progress,
                                on_result=on_result, probe=probe, live=live)


def run_trace(settings: Settings, *, object: int = 5, planner: str = "mi", case: str = "iii", trial: int = 0, prepared: Prepared | None = None) -> TrialResult:
    """Replay one trial of a case's campaign with its per-step object
    probabilities, like thesis Table 7.8 (default: object 6 = index 5, its
    first trial, occluded, case iii).  Same scene, start, noise and keys as in
    :func:`run_case` with the same settings."""
    c = CASES[case]
    settings = case_settings(c, settings)
    prepared = prepared or prepare(settings, databases=(c.database,))
    model = case_model(prepared, c)
    rig = make_rig(settings, c.cameras, seed=settings.seed)
    if not 0 <= trial < settings.trials_per_object:
        raise ValueError(f"trial must be in [0, {settings.trials_per_object}), got {trial}")
    (spec,) = [s for s in case_trials(c, settings, rig, model.n_objects, model.n_poses, objects=[object])
               if s.trial == object * settings.trials_per_object + trial]
    rec = campaign_recognizer(model, planner, settings, rig_travel_times(rig))
    (res,) = run_campaign(rec, rig, [spec], key=jr.PRNGKey(settings.seed + 1), batch=1, seed=settings.seed, trace=True)
    return res
