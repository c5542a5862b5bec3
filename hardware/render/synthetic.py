"""``SyntheticRig``: the thesis's two-camera rig (ch. 6, app. C) as a rendered scene.

Cameras sit at the eye positions of a :class:`~..geometry.positions.CameraTable` (the
appendix-C kinematics turn planner angles into those positions) and always look
at the object centre.  Each position has its own zoom (``Intrinsics.fov``), as
the thesis's predefined zoom tables.  Rendering is pybullet's CPU TinyRenderer
in DIRECT mode (:mod:`.scene`), one client per rig.

Per capture, optionally (seeded): brightness noise ``y <- g y + n`` with gain
``g ~ N(1, brightness^2)`` and pixel noise ``n ~ N(0, pixel^2)`` gray levels,
and a random integer pixel offset of at most ``max_shift`` in x and y -- the
perturbations of the thesis's training set (ch. 7), here applied to captures.

The true occluded fraction of the object in an image is measured from the
segmentation mask: ``1 - (object pixels with the boards) / (object pixels
without them)``.
"""

from __future__ import annotations

import dataclasses
import hashlib
from typing import Sequence

import numpy as np

from .occluders import OccluderLayout
from ..geometry.positions import CameraTable, default_table
from ..rigs.rig import Capture, RigError, SeededCaptures
from .scene import Intrinsics, Lighting, ObjectSpec, Scene

__all__ = ["Noise", "OffGrid", "Perturb", "SyntheticRig"]


@dataclasses.dataclass(frozen=True)
class Noise:
    """Per-capture perturbations (all off by default).

    Attributes:
        brightness: standard deviation of the multiplicative gain around 1.
        pixel: standard deviation of additive per-pixel noise (gray levels).
        max_shift: largest random image offset in pixels (x and y, integers).
    """

    brightness: float = 0.0
    pixel: float = 0.0
    max_shift: int = 0

    def __post_init__(self):
        if self.brightness < 0 or self.pixel < 0 or self.max_shift < 0:
            raise ValueError(f"noise settings must be >= 0, got {self}")

    @property
    def off(self) -> bool:
        return self.brightness == 0 and self.pixel == 0 and self.max_shift == 0


@dataclasses.dataclass(frozen=True)
class Perturb:
    """Small departures from the training views, for held-out calibration renders.

    Attributes:
        yaw_deg: object yaw offset drawn uniformly in ``[-yaw_deg, yaw_deg]`` degrees.
        eye_offset: camera displacement, isotropic Gaussian with sd
            ``eye_offset / sqrt(3)`` times the eye-object distance per axis
            (the camera keeps looking at the object centre).
        light: relative jitter of the light direction (Gaussian, per axis) and of
            the ambient / diffuse coefficients (gain ``1 + light · N(0, 1)``).
        noise: the per-capture perturbations on top.
    """

    yaw_deg: float = 3.0
    eye_offset: float = 0.02
    light: float = 0.1
    noise: Noise = Noise(brightness=0.05, pixel=2.0, max_shift=2)

    def __post_init__(self):
        _check_amounts(self, ("yaw_deg", "eye_offset", "light"), "perturbations")


def _check_amounts(obj, names, what: str) -> None:
    """Every named field finite and >= 0 (NaN fails too), else one ValueError."""
    bad = [f"{n}={getattr(obj, n)!r}" for n in names
           if isinstance(getattr(obj, n), bool) or not isinstance(getattr(obj, n), (int, float))
           or not (0 <= getattr(obj, n) < float("inf"))]
    if bad:
        raise ValueError(f"{what} must be >= 0 and finite, got {', '.join(bad)}")


@dataclasses.dataclass(frozen=True)
class OffGrid:
    """Campaign captures off the training grid (not in the thesis): the
    :class:`Perturb` departures, but drawn per *trial* (the yaw) and per
    *capture* (camera eye and light) instead of per held-out image.

    Attributes:
        yaw_deg: bound of the trial's object yaw offset, drawn uniformly in
            ``[-yaw_deg, yaw_deg]`` by :func:`jaxrecog.campaign.plan_trials`
            from the trial's generator (the object sits there for the whole
            trial, every planner sees it) and given to
            :meth:`SyntheticRig.reset`.
        eye_offset: per capture and camera, the eye moves by an isotropic
            Gaussian with sd ``eye_offset / sqrt(3)`` times the eye-object
            distance per axis, still looking at the object centre
            (:class:`Perturb`'s ``eye_offset``).
        light: per capture, relative jitter of the light direction and of the
            ambient / diffuse gains (:class:`Perturb`'s ``light``).

    The eye and light draws come from the rig's capture generator, which the
    campaigns reseed per (seed, trial, step), so they do not depend on the
    rig pool; all zero (the default) draws nothing, so the captures are
    exactly the on-grid ones.
    """

    yaw_deg: float = 0.0
    eye_offset: float = 0.0
    light: float = 0.0

    def __post_init__(self):
        _check_amounts(self, ("yaw_deg", "eye_offset", "light"), "off-grid amounts")

    @property
    def off(self) -> bool:
        return self.yaw_deg == 0 and self.eye_offset == 0 and self.light == 0


def _jitter_eye(eye: np.ndarray, centre: np.ndarray, scale: float, rng: np.random.Generator) -> np.ndarray:
    """``eye`` displaced by N(0, (scale · |eye - centre| / sqrt 3)^2) per axis
    (always draws 3 normals, so a zero scale keeps the stream aligned)."""
    dist = float(np.linalg.norm(eye - centre))
    return eye + rng.standard_normal(3) * scale * dist / np.sqrt(3.0)


def _jitter_light(light: Lighting, j: float, rng: np.random.Generator) -> Lighting:
    """``light`` with its direction scaled by ``1 + j N(0, 1)`` per axis and its
    ambient / diffuse coefficients by gains ``1 + j N(0, 1)`` clipped to [0.5, 1.5]."""
    direction = np.asarray(light.direction) * (1.0 + j * rng.standard_normal(3))
    gain = np.clip(1.0 + j * rng.standard_normal(2), 0.5, 1.5)
    return dataclasses.replace(light, direction=tuple(float(x) for x in direction),
                               ambient=float(light.ambient * gain[0]), diffuse=float(light.diffuse * gain[1]))


class SyntheticRig(SeededCaptures):
    """A :class:`~..rigs.rig.Rig` whose images are renders of the scene.

    Args:
        table: camera positions (default :func:`~..geometry.positions.default_table`, 32 x 7);
            any number of cameras.
        objects: object specs (default the 8 of :func:`~.scene.default_objects`).
        n_poses: poses per object, pose ``p`` at ``360° p / n_poses``.
        intrinsics: image size, clip planes and zoom rule.
        lighting: the fixed light.
        noise: per-capture perturbations (default none).
        seed: seeds the generator of the perturbations.
        off_grid: per-capture eye and light jitter (:class:`OffGrid`; the
            rig does not use its ``yaw_deg``: a trial's yaw offset comes
            through :meth:`reset`); ``None`` = on the training grid.
        clean_counts: the cache of unoccluded object pixel counts per
            (object, pose, yaw, eye), the denominator of the occluded
            fraction; pass one dict to several rigs and they share what they
            count (the key includes the objects, intrinsics and workspace, so
            unlike rigs do not mix).  Default: the rig's own.

    Attributes:
        fov: ``fov[i][v]``, vertical field of view (degrees) of camera ``i`` at position ``v``.
        radius: bounding radius of the objects about the object centre (m).
    """

    def __init__(
        self,
        table: CameraTable | None = None,
        *,
        objects: Sequence[ObjectSpec] | None = None,
        n_poses: int = 4,
        intrinsics: Intrinsics = Intrinsics(),
        lighting: Lighting = Lighting(),
        noise: Noise = Noise(),
        seed: int = 0,
        off_grid: OffGrid | None = None,
        clean_counts: dict | None = None,
    ):
        self.table = default_table() if table is None else table
        if self.table.n_cameras < 1 or min(self.table.positions) < 1:
            raise ValueError(f"the camera table needs >= 1 camera with >= 1 position, got {self.table.positions}")
        self.intrinsics = intrinsics
        self.noise = noise
        if off_grid is not None and not isinstance(off_grid, OffGrid):
            raise TypeError(f"off_grid must be an OffGrid or None, got {type(off_grid).__name__}")
        self.off_grid = off_grid if off_grid is not None and not off_grid.off else None
        self.scene = Scene(objects, self.table.workspace.object_xyz, n_poses, lighting)
        self.radius = self.scene.radius
        self._centre = np.asarray(self.scene.centre)
        self.fov = tuple(tuple(self._fov(view.eye) for view in views) for views in self.table.views)
        self._rng = np.random.default_rng(seed)
        self._state: tuple[int, int] | None = None
        self._layout: OccluderLayout | None = None
        self._config: tuple[int, ...] | None = None
        self._clean_pixels: dict[tuple, int] = {} if clean_counts is None else clean_counts
        # what else a clean count depends on, so that a dict shared by unlike rigs cannot mix them up
        self._clean_sig = hashlib.sha1(repr((self.intrinsics, self.scene.objects, self.scene.n_poses,
                                             tuple(self.table.workspace.object_xyz))).encode()).hexdigest()[:16]

    # -- Rig protocol
    @property
    def positions(self) -> tuple[int, ...]:
        return self.table.positions

    @property
    def image_shape(self) -> tuple[int, int]:
        return (self.intrinsics.height, self.intrinsics.width)

    @property
    def n_objects(self) -> int:
        return len(self.scene.objects)

    @property
    def n_poses(self) -> int:
        return self.scene.n_poses

    def reset(self, object: int, pose: int, occluders: OccluderLayout | None = None, *,
              yaw_offset_deg: float = 0.0) -> None:
        """Put ``object`` in ``pose`` on the turn-table, turned a further
        ``yaw_offset_deg`` degrees off the training grid (a trial's
        :attr:`~jaxrecog.driver.TrialSpec.yaw_offset`); ``occluders`` is an
        :class:`~.occluders.OccluderLayout` or ``None`` (clean scene)."""
        if occluders is not None and not isinstance(occluders, OccluderLayout):
            raise TypeError(f"occluders must be an OccluderLayout or None, got {type(occluders).__name__}")
        yaw = yaw_offset_deg
        if isinstance(yaw, bool) or not isinstance(yaw, (int, float, np.floating, np.integer)) or not np.isfinite(yaw):
            raise ValueError(f"yaw_offset_deg must be a finite number of degrees, got {yaw!r}")
        try:
            self.scene.set_object(object, pose, float(yaw))
        except ValueError as err:
            raise RigError(str(err)) from err
        self._state = (int(object), int(pose))
        layout = occluders if occluders is not None and len(occluders) else None
        self.scene.set_occluders(layout.boards if layout else (), key=layout)
        self._layout = layout

    def move(self, configuration: Sequence[int]) -> None:
        """Move camera ``i`` to position ``configuration[i]``."""
        cfg = tuple(int(v) for v in configuration)
        if len(cfg) != self.table.n_cameras:
            raise RigError(f"configuration {cfg} has {len(cfg)} entries, the rig has {self.table.n_cameras} cameras")
        for i, (v, n) in enumerate(zip(cfg, self.positions)):
            if not 0 <= v < n:
                raise RigError(f"configuration {cfg}: camera {i} position {v} is out of range 0..{n - 1}")
        self._config = cfg

    def capture(self) -> Capture:
        """One ``uint8 [H, W]`` image per camera and its true occluded fraction."""
        if self._config is None:
            raise RigError("capture() before move(): the cameras have no position yet")
        images, fractions = [], []
        jit = self.off_grid
        light = self.scene.lighting
        if jit is not None and jit.light:
            self.scene.lighting = _jitter_light(light, jit.light, self._rng)  # one light per capture
        try:
            for i, v in enumerate(self._config):
                eye = self.table.views[i][v].eye
                moved = jit is not None and jit.eye_offset > 0
                if moved:
                    eye = tuple(float(c) for c in _jitter_eye(np.asarray(eye, dtype=float), self._centre,
                                                              jit.eye_offset, self._rng))
                img, frac = self._render(i, eye, self.noise, cache=not moved)
                images.append(img)
                fractions.append(frac)
        finally:
            self.scene.lighting = light
        return Capture.of(images, fractions)

    # -- extras
    def render_at(self, camera: int, eye: Sequence[float], *, noisy: bool = True) -> tuple[np.ndarray, float]:
        """Render camera ``camera`` from an arbitrary ``eye`` (x, y, z), looking at
        the object, zoomed by the same rule as the table's positions.

        Returns:
            (``uint8 [H, W]`` image, true occluded fraction of the object).
        """
        if not 0 <= int(camera) < self.table.n_cameras:
            raise RigError(f"camera {camera} is out of range 0..{self.table.n_cameras - 1}")
        eye = tuple(float(c) for c in eye)
        if len(eye) != 3 or not np.all(np.isfinite(eye)):
            raise RigError(f"eye must be 3 finite coordinates, got {eye}")
        return self._render(int(camera), eye, self.noise if noisy else Noise())

    def render_clean(self, camera: int, position: int) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free image and object mask (``bool [H, W]``) at a table position,
        with the current occluders in place."""
        eye = self.table.views[camera][position].eye
        self._need_state()
        self.scene.show_occluders(self._layout is not None)
        img, seg = self.scene.render(eye, self._fov(eye), self.intrinsics)
        return img, np.isin(seg, self.scene.object_ids)

    def render_noisy(self, camera: int, position: int, noise: Noise) -> tuple[np.ndarray, float]:
        """Image at a table position with the given perturbations (for test sets)."""
        return self._render(camera, self.table.views[camera][position].eye, noise)

    def render_perturbed(self, camera: int, position: int, perturb: Perturb,
                         rng: np.random.Generator) -> tuple[np.ndarray, float]:
        """Image near a table position: the object turned a few degrees, the
        camera displaced, the light changed and ``perturb.noise`` applied (all
        drawn from ``rng``, capture noise from the rig's generator); the scene
        is restored afterwards.  Returns (image, true occluded fraction)."""
        self._need_state()
        obj, pose = self._state
        base_yaw = self.scene._current[2] if self.scene._current is not None else 0.0
        eye = np.asarray(self.table.views[camera][position].eye, dtype=float)
        yaw = float(rng.uniform(-perturb.yaw_deg, perturb.yaw_deg)) if perturb.yaw_deg else 0.0
        eye = _jitter_eye(eye, self._centre, perturb.eye_offset, rng)
        light = self.scene.lighting
        if perturb.light:
            self.scene.lighting = _jitter_light(light, perturb.light, rng)
        try:
            self.scene.set_object(obj, pose, base_yaw + yaw)
            return self._render(camera, tuple(eye), perturb.noise)
        finally:
            self.scene.lighting = light
            self.scene.set_object(obj, pose, base_yaw)

    def close(self) -> None:
        self.scene.close()

    def __enter__(self) -> "SyntheticRig":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- internals
    def _need_state(self) -> None:
        if self._state is None:
            raise RigError("no object on the turn-table: call reset(object, pose) first")

    def _fov(self, eye: Sequence[float]) -> float:
        dist = float(np.linalg.norm(np.asarray(eye, dtype=float) - self._centre))
        try:
            return self.intrinsics.fov(self.radius, dist)
        except ValueError as err:
            raise RigError(f"eye {tuple(eye)}: {err}") from err

    def _render(self, camera: int, eye: Sequence[float], noise: Noise, cache: bool = True) -> tuple[np.ndarray, float]:
        self._need_state()
        fov = self._fov(eye)
        shift = (0, 0)
        if noise.max_shift:
            shift = tuple(int(s) for s in self._rng.integers(-noise.max_shift, noise.max_shift + 1, size=2))
        if self._layout is None:
            self.scene.show_occluders(False)
            img, _ = self.scene.render(eye, fov, self.intrinsics, shift)
            frac = 0.0
        else:
            self.scene.show_occluders(True)
            img, seg = self.scene.render(eye, fov, self.intrinsics, shift)
            seen = int(np.isin(seg, self.scene.object_ids).sum())
            clean = self._clean_count(eye, fov, cache)
            frac = min(max(1.0 - seen / clean, 0.0), 1.0)
        if noise.brightness or noise.pixel:
            y = img.astype(np.float32)
            if noise.brightness:
                y *= max(0.0, 1.0 + noise.brightness * float(self._rng.standard_normal()))
            if noise.pixel:
                y += noise.pixel * self._rng.standard_normal(y.shape, dtype=np.float32)
            img = np.clip(np.rint(y), 0, 255).astype(np.uint8)
        return img, frac

    def _clean_count(self, eye: Sequence[float], fov: float, cache: bool = True) -> int:
        # a jittered eye is never seen twice: count it without filling the cache
        key = (self._clean_sig, self.scene._current, tuple(round(float(c), 9) for c in eye))
        count = self._clean_pixels.get(key) if cache else None
        if count is None:
            self.scene.show_occluders(False)
            _, seg = self.scene.render(eye, fov, self.intrinsics)
            count = int(np.isin(seg, self.scene.object_ids).sum())
            if count == 0:
                raise RigError(f"the object is not in view from eye {tuple(eye)}")
            if cache:
                self._clean_pixels[key] = count
        return count
