"""Live view of recognition trials in rerun (the ``rerun`` extra).

:class:`RerunRecorder` is an observer of the trial driver: pass it as
``on_step`` to :func:`jaxrecog.driver.run_trials` (or call
:meth:`RerunRecorder.log_step` from a control loop of its own) and every step
of every trial is logged, on the sequence timelines ``trial`` and ``step``
(1-based), under ``/<label>`` (the planner in a campaign):

==============================  =============================================
``camera/<i>/image``            camera ``i``'s image of the step
``belief/objects``              P(object) after the step (bar chart)
``belief/poses``                P(object, pose), an ``objects x poses`` tensor
``occlusion/camera<i>``         estimated occluded fraction of camera ``i``:
                                ``sum_c P(c) sum_k P_i(k | c) level_k``
``occlusion/camera<i>/true``    the true fraction, where the rig knows it
``planner/scores``              the planner's score of every configuration,
                                one tensor axis per camera (32 x 7 on the
                                thesis rig; a configuration it cannot score,
                                ``-inf``, shows as the lowest score)
``rig/object``, ``rig/camera<i>``  the object and each camera in 3-D, from the
                                rig's geometry (:func:`rig_geometry`), when it
                                has one (a replayed database has none)
``log``                         one line: configuration, decision, next move
==============================  =============================================

rerun is imported only when a recorder is made: the core imports without
it, and without it a recorder raises :class:`LiveViewError` naming the extra.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import shutil
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

__all__ = ["CampaignView", "LiveViewError", "RerunRecorder", "RigGeometry", "import_rerun", "occlusion_estimates", "rig_geometry"]

#: what to install for the live view (the one line a missing rerun gives)
INSTALL_HINT = "pip install 'jaxrecog[rerun]'"


class LiveViewError(RuntimeError):
    """The live view cannot start (rerun not installed, no viewer to reach)."""


def import_rerun():
    """The ``rerun`` module, or :class:`LiveViewError` naming the extra that installs it."""
    try:
        return importlib.import_module("rerun")
    except ImportError:
        raise LiveViewError(f"the live view needs the rerun SDK, which is not installed: {INSTALL_HINT}") from None


@dataclasses.dataclass(frozen=True)
class RigGeometry:
    """Where the object and each camera position are, in metres.

    Attributes:
        object_xyz: the object's centre.
        eyes: one ``[V_i, 3]`` array per camera: the eye at each position.
    """

    object_xyz: tuple[float, float, float]
    eyes: tuple[np.ndarray, ...]


def rig_geometry(rig) -> RigGeometry | None:
    """The geometry of a rig that knows it: a rig file's table (hardware rigs),
    a rig's ``table`` (the synthetic rig; appendix-C kinematics) or its
    ``geometry`` (the hand-held rig's layout); ``None`` for one without (a
    replayed database)."""
    geometry = getattr(rig, "geometry", None)
    if hasattr(geometry, "eyes") and hasattr(geometry, "object_xyz"):
        return RigGeometry(tuple(float(x) for x in geometry.object_xyz),
                           tuple(np.asarray(e, dtype=float).reshape(-1, 3) for e in geometry.eyes))
    table = getattr(getattr(rig, "config", None), "table", None)
    table = table if table is not None else getattr(rig, "table", None)
    if table is None or not hasattr(table, "views"):
        return None
    eyes = tuple(np.array([view.eye for view in views], dtype=float).reshape(-1, 3) for views in table.views)
    return RigGeometry(tuple(float(x) for x in table.workspace.object_xyz), eyes)


def occlusion_estimates(posterior, levels: Sequence[float]) -> np.ndarray:
    """``[n_cameras]`` expected occluded fraction per camera under a belief
    (:class:`jaxrecog.kernels.belief.Belief`):
    ``sum_c P(c) sum_k P_i(k | c) levels[k]``."""
    pc = np.exp(np.asarray(posterior.log_pc, dtype=float))
    lv = np.asarray(levels, dtype=float)
    out = []
    for log_pk in posterior.log_pk:
        pk = np.exp(np.asarray(log_pk, dtype=float))  # [C, L]
        out.append(float(pc @ (pk @ lv[:pk.shape[1]])))
    return np.asarray(out)


def _viewer() -> str | None:
    """The rerun viewer program: on PATH, or beside this Python (a venv's
    ``bin/``, where ``pip install rerun-sdk`` puts it, run without activating)."""
    beside = Path(sys.executable).with_name("rerun")
    return shutil.which("rerun") or (str(beside) if beside.is_file() else None)


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Rotation (columns: camera x right, y down, z forward in the world) of a
    camera at ``eye`` looking at ``target``, upright (world z up)."""
    forward = target - eye
    forward = forward / (np.linalg.norm(forward) or 1.0)
    up = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(forward, right), forward], axis=1)


class RerunRecorder:
    """Log every step of recognition trials to rerun (module doc: what goes where).

    Args:
        model: the sensor model the recognizer runs (objects, poses, camera
            positions, occlusion levels).
        geometry: the rig's :class:`RigGeometry` (:func:`rig_geometry`), or
            ``None`` to log no 3-D view.
        save: write the recording to this ``.rrd`` file (headless).
        spawn: start a viewer and stream to it (``rr.spawn``).
        connect: stream to a running viewer at this gRPC address
            (``rerun+http://HOST:PORT/proxy``).
        label: entity path prefix (e.g. the planner), ``""`` for none.
        recording: a ``rerun.RecordingStream`` to log to instead (tests, notebooks).

    The recorder is the ``on_step`` callable of :func:`jaxrecog.driver.run_trials`
    (run it with ``trace=True``: the belief and scores come from the step's trace).
    """

    def __init__(self, model, *, geometry: RigGeometry | None = None, save=None, spawn: bool = False,
                 connect: str | None = None, label: str = "", recording: Any = None):
        self.rr = import_rerun()
        self.positions = tuple(int(v) for v in model.positions)
        self.n_objects, self.n_poses = int(model.n_objects), int(model.n_poses)
        self.levels = tuple(float(x) for x in model.levels)
        self.image_shape = tuple(int(v) for v in model.image_shape)
        self.geometry = geometry
        self.label = label.strip("/")
        self._logged_static = False
        if recording is None:
            recording = self._stream(save, spawn, connect)
        self.recording = recording

    def _stream(self, save, spawn: bool, connect: str | None):
        """A recording stream whose sinks are the file ``save``, a spawned
        viewer and/or the viewer at ``connect`` (rerun's ``set_sinks``)."""
        rr = self.rr
        if save is None and not spawn and connect is None:
            raise LiveViewError("a rerun recorder needs somewhere to send the recording: save, spawn or connect")
        recording = rr.RecordingStream("jaxrecog")
        viewer = _viewer() if spawn else None
        if spawn and sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                               or os.environ.get("WAYLAND_DISPLAY")):
            raise LiveViewError("rerun: no display here for a viewer (DISPLAY unset); --rerun-save FILE.rrd "
                                "records without one")
        if spawn and viewer is None:
            raise LiveViewError("rerun: no viewer program 'rerun' on PATH or beside this Python (rerun-sdk installs "
                                "it); --rerun-save FILE.rrd records without one")
        try:
            if spawn:  # the viewer, listening on its default address
                rr.spawn(connect=False, executable_path=viewer, recording=recording)
            sinks = [rr.FileSink(str(save))] if save is not None else []
            if spawn or connect is not None:
                sinks.append(rr.GrpcSink(connect))
            recording.set_sinks(*sinks)
        except Exception as e:  # noqa: BLE001 - rerun raises its own kinds; one line for the user
            raise LiveViewError(f"rerun: {' '.join(str(e).split())}") from None
        return recording

    def for_label(self, label: str) -> "RerunRecorder":
        """The same recording under another entity prefix (one per planner of a campaign)."""
        other = object.__new__(RerunRecorder)
        other.__dict__.update(self.__dict__)
        other.label = label.strip("/")
        return other

    def _path(self, *parts) -> str:
        return "/".join(p for p in (self.label, *map(str, parts)) if p)

    def _log_static(self) -> None:
        """Every position of every camera as points, once (static)."""
        rr, rec, g = self.rr, self.recording, self.geometry
        self._logged_static = True
        if g is None:
            return
        for i, eyes in enumerate(g.eyes):
            rec.log(self._path("rig", f"positions{i}"), rr.Points3D(eyes, radii=0.005), static=True)

    def __call__(self, record) -> None:
        """``on_step`` of :func:`jaxrecog.driver.run_trials`: log one :class:`~jaxrecog.driver.StepRecord`."""
        self.log_step(record.spec.trial, record.step, record.config, record.capture.images, record.decision,
                      occluded=record.capture.occluded)

    def log_step(self, trial: int, step: int, config: Sequence[int], images, decision,
                 occluded: Sequence[float] = ()) -> None:
        """Log step ``step`` (0-based) of ``trial``: the images taken at
        ``config`` and the recognizer's ``decision`` (with its trace)."""
        rr, rec = self.rr, self.recording
        if not self._logged_static:
            self._log_static()
        rec.set_time("trial", sequence=int(trial))
        rec.set_time("step", sequence=int(step) + 1)
        for i, image in enumerate(np.asarray(images)):
            rec.log(self._path("camera", i, "image"), rr.Image(np.asarray(image, np.uint8)))
        trace = decision.trace
        if trace is not None:
            self._log_belief(trace)
        for i, x in enumerate(occluded):
            rec.log(self._path("occlusion", f"camera{i}", "true"), rr.Scalars(float(x)))
        config = tuple(int(v) for v in config)
        self._log_rig(config)
        stop = bool(np.asarray(decision.stop))
        nxt = "stop" if stop else f"next {tuple(int(v) for v in np.asarray(decision.next_config))}"
        rec.log(self._path("log"), rr.TextLog(
            f"trial {trial} step {step + 1}: configuration {config}; object {int(decision.object)}, "
            f"pose {int(decision.pose)} with P = {float(decision.probability):.3f}; {nxt}"))

    def _log_belief(self, trace) -> None:
        rr, rec = self.rr, self.recording
        rec.log(self._path("belief", "objects"), rr.BarChart(np.asarray(trace.object_probs, dtype=float)))
        joint = np.asarray(trace.class_probs, dtype=float).reshape(self.n_objects, self.n_poses)
        rec.log(self._path("belief", "poses"), rr.Tensor(joint, dim_names=("object", "pose")))
        for i, x in enumerate(occlusion_estimates(trace.posterior, self.levels)):
            rec.log(self._path("occlusion", f"camera{i}"), rr.Scalars(float(x)))
        scores = np.asarray(trace.scores, dtype=float)
        finite = scores[np.isfinite(scores)]
        scores = np.where(np.isfinite(scores), scores, finite.min() if finite.size else 0.0)
        names = tuple(f"camera {i + 1} position" for i in range(len(self.positions)))
        rec.log(self._path("planner", "scores"), rr.Tensor(scores.reshape(self.positions), dim_names=names))

    def _log_rig(self, config: tuple[int, ...]) -> None:
        """The object and each camera where ``config`` puts it, looking at the object."""
        rr, rec, g = self.rr, self.recording, self.geometry
        if g is None:
            return
        target = np.asarray(g.object_xyz, dtype=float)
        h, w = self.image_shape
        rec.log(self._path("rig", "object"), rr.Points3D([target], radii=0.02))
        for i, v in enumerate(config):
            eye = np.asarray(g.eyes[i][v], dtype=float)
            rec.log(self._path("rig", f"camera{i}"),
                    rr.Transform3D(translation=eye, mat3x3=_look_at(eye, target)),
                    rr.Pinhole(focal_length=float(w), width=w, height=h, image_plane_distance=0.05))

    def close(self) -> None:
        """Flush and end the recording (idempotent)."""
        rec, self.recording = self.recording, None
        if rec is not None:
            try:
                rec.flush()
                rec.disconnect()
            except Exception as e:  # noqa: BLE001 - a viewer gone or never reached: one line for the user
                raise LiveViewError(f"rerun: {' '.join(str(e).split())}") from None


class CampaignView:
    """One rerun recording for a whole campaign: ``view(label, model, rig)``
    is the ``on_step`` observer of one planner's trials (a
    :class:`RerunRecorder` under ``/<label>``, the 3-D view from ``rig``),
    the observer factory ``live`` of :func:`jaxrecog.campaigns.run_case` and
    :func:`jaxrecog.campaigns.run_dataset`.  ``sinks``: ``save``, ``spawn``,
    ``connect`` as for :class:`RerunRecorder`.  rerun is checked for here,
    before any trial runs."""

    def __init__(self, **sinks):
        import_rerun()
        self.sinks = sinks
        self._first: RerunRecorder | None = None

    def __call__(self, label: str, model, rig) -> RerunRecorder:
        if self._first is None:
            self._first = RerunRecorder(model, geometry=rig_geometry(rig), label=label, **self.sinks)
            return self._first
        return self._first.for_label(label)

    def close(self) -> None:
        """End the recording (idempotent)."""
        if self._first is not None:
            self._first.close()
