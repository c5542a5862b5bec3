"""Augmentation of the training images (thesis §4.3, §7.1): DB1 and DB2.

Each training image ``x`` yields ``samples_per_image`` samples per occlusion
level.  One sample is (pixel model, before 8-bit rounding and clipping)::

    y = m ⊙ (g ⊙ G_σ A_{θ,a} S_d x) + b·1 + n,
    d ~ U{-s..s}²            integer pixel shift, edge pixels replicated
    A_{θ,a}                  in-plane rotation by θ ~ U(-max_rotation, max_rotation)
                             degrees and scaling by 1 + a, a ~ U(-max_scale, max_scale),
                             about the image centre ((W-1)/2, (H-1)/2):
                             ``cv2.warpAffine``, bilinear, border replicated
                             (θ > 0: counter-clockwise on screen, OpenCV's sense);
                             applied to the shifted image, float32, not rounded
    G_σ                      Gaussian blur, σ ~ U(blur_sigma) pixels (``cv2.GaussianBlur``,
                             kernel size from σ, border replicated; σ = 0: none)
    g = 1 + resize(c)        local gain: a smooth multiplicative field, the
                             bilinear upsampling (``cv2.resize``, INTER_LINEAR) of a
                             ``gain_cells × gain_cells`` grid c ~ U(-gain_amplitude,
                             gain_amplitude) to H × W (so |g - 1| <= gain_amplitude)
    m                        occlusion mask (0 on the occluder, 1 elsewhere)
    (1 - m) v                the occluder's own gray level, v ~ U(occluder_gray); off
                             by default (v = 0: black, the thesis's occluder)
    b ~ N(0, brightness_sigma²)   global brightness change of the image
    n ~ N(0, noise_sigma² I)      per-pixel camera noise

so the occluder is a black (or, with ``occluder_gray``, a uniformly gray)
object in the scene that the camera then images with the same brightness
change and noise as everything else.  A real occluder is rarely black (the
synthetic rig's boards are cardboard gray); ``occluder_gray = (lo, hi)``
draws its gray level per sample (not in the thesis; off by default).  ``A``, ``G``
and ``g`` model what a real capture does off the training grid (a slightly
turned or nearer camera, defocus, uneven lighting); they are *off by
default* (``max_rotation = max_scale = gain_amplitude = 0``, ``blur_sigma =
(0, 0)``), and then the samples are bit-exact those of the model without them.
When one is on, training computes every sample in pixel space (one OpenCV
call per sample and step), so it is slower than the level-0 shift table.
Their random numbers come from a separate generator
(``SeedSequence((seed, camera, position, level, 2))``), so switching them on
does not change the shifts, occluders, brightness or noise of any sample.

*DB1* has one level, 0 (no occluder).  *DB2* adds levels 5, 10, 15, 20, 25 % of
the image area; each sample's occluder is one of square, rectangle, circle,
triangle, trapezoid (chosen uniformly), drawn with OpenCV, at a random place
fully inside the image.  Occluder shapes come from a bank of
``n_templates`` random templates per (level, shape) — random aspect ratio,
orientation (any angle) and skew — each calibrated so that its pixel count is within
``±0.5`` points of the level (the promise is ``±1`` point).  Level 0 samples
are the DB1 samples.

Defaults (documented here, used everywhere): ``samples_per_image=100``,
``noise_sigma=4.0`` and ``brightness_sigma=8.0`` gray levels,
``max_shift=3`` pixels.

Everything is reproducible from an integer seed: the random numbers for
(camera, position, level) come from ``SeedSequence((seed, camera, position,
level))``, so the order of processing never changes the result.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = [
    "SHAPES",
    "DB1_LEVELS",
    "DB2_LEVELS",
    "AugmentParams",
    "OccluderBank",
    "SamplePlan",
    "levels_for",
    "occluder_bank",
    "draw_plan",
    "plan_rng",
    "capture_rng",
    "capture_transform",
    "ShiftWindows",
    "apply_geometry",
    "augment_images",
]

SHAPES = ("square", "rectangle", "circle", "triangle", "trapezoid")
DB1_LEVELS = (0.0,)
DB2_LEVELS = (0.0, 0.05, 0.10, 0.15, 0.20, 0.25)
CALIBRATION_TOL = 0.005  # fraction of the image area (half the promised ±1 point)


def levels_for(kind: str) -> tuple[float, ...]:
    """Occlusion levels of a database kind: ``"DB1"`` or ``"DB2"``."""
    if kind == "DB1":
        return DB1_LEVELS
    if kind == "DB2":
        return DB2_LEVELS
    raise ValueError(f"unknown database kind {kind!r}: expected 'DB1' or 'DB2'")


@dataclasses.dataclass(frozen=True)
class AugmentParams:
    """Augmentation settings (see the module docstring for the model)."""

    samples_per_image: int = 100
    noise_sigma: float = 4.0
    brightness_sigma: float = 8.0
    max_shift: int = 3
    shapes: tuple[str, ...] = SHAPES
    n_templates: int = 16
    #: Common random numbers across the images of one position: sample ``j`` of
    #: every image uses the same shift, brightness, noise and occluder.  Two
    #: classes whose clean images are identical (the look-alike pairs seen from
    #: a view without the sticker) then get identical Gaussians, instead of
    #: Gaussians that differ by sampling noise alone — differences the
    #: recognizer would otherwise read as evidence.
    shared_draws: bool = True
    #: in-plane rotation: θ ~ U(-max_rotation, max_rotation), degrees (0 = off)
    max_rotation: float = 0.0
    #: scale 1 + a, a ~ U(-max_scale, max_scale), a fraction < 1 (0 = off)
    max_scale: float = 0.0
    #: Gaussian blur σ ~ U(lo, hi) pixels; ``(0, 0)`` = off
    blur_sigma: tuple[float, float] = (0.0, 0.0)
    #: local gain field amplitude, a fraction < 1 (0 = off)
    gain_amplitude: float = 0.0
    #: control grid of the gain field: ``gain_cells × gain_cells`` values (>= 2)
    gain_cells: int = 3
    #: the occluder's gray level v ~ U(lo, hi) (0..255) per sample; ``(0, 0)`` =
    #: black, the thesis's occluder
    occluder_gray: tuple[float, float] = (0.0, 0.0)

    @property
    def gray_occluders(self) -> bool:
        """Whether the occluder's gray level is drawn (else it is black)."""
        return self.occluder_gray[1] > 0

    @property
    def capture(self) -> bool:
        """Whether any of rotation, scale, blur, local gain is on."""
        return bool(self.max_rotation > 0 or self.max_scale > 0 or self.blur_sigma[1] > 0
                    or self.gain_amplitude > 0)

    def __post_init__(self):
        object.__setattr__(self, "blur_sigma", tuple(float(x) for x in self.blur_sigma))
        object.__setattr__(self, "occluder_gray", tuple(float(x) for x in self.occluder_gray))
        if len(self.occluder_gray) != 2 or not all(np.isfinite(x) and 0 <= x <= 255 for x in self.occluder_gray) \
                or self.occluder_gray[0] > self.occluder_gray[1]:
            raise ValueError(f"occluder_gray must be (lo, hi) gray levels with 0 <= lo <= hi <= 255, "
                             f"got {self.occluder_gray}")
        for name in ("max_rotation", "max_scale", "gain_amplitude"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v}")
        if self.max_rotation > 180:
            raise ValueError(f"max_rotation must be <= 180 degrees, got {self.max_rotation}")
        if self.max_scale >= 1:
            raise ValueError(f"max_scale must be < 1 (a fraction of the size), got {self.max_scale}")
        if self.gain_amplitude >= 1:
            raise ValueError(f"gain_amplitude must be < 1 (a fraction of the gain), got {self.gain_amplitude}")
        if len(self.blur_sigma) != 2 or not all(np.isfinite(x) and x >= 0 for x in self.blur_sigma) \
                or self.blur_sigma[0] > self.blur_sigma[1]:
            raise ValueError(f"blur_sigma must be (lo, hi) with 0 <= lo <= hi, got {self.blur_sigma}")
        if self.gain_cells < 2:
            raise ValueError(f"gain_cells must be >= 2, got {self.gain_cells}")
        if self.samples_per_image < 2:
            raise ValueError("samples_per_image must be at least 2 (a variance needs two samples)")
        if self.noise_sigma < 0 or self.brightness_sigma < 0 or self.max_shift < 0:
            raise ValueError("noise_sigma, brightness_sigma and max_shift must be >= 0")
        unknown = [s for s in self.shapes if s not in SHAPES]
        if unknown or not self.shapes:
            raise ValueError(f"shapes must be a non-empty subset of {SHAPES}, got {self.shapes}")
        if self.n_templates < 1:
            raise ValueError("n_templates must be >= 1")


# --------------------------------------------------------------------------
# occluder templates
# --------------------------------------------------------------------------

def _polygon(shape: str, rng: np.random.Generator) -> np.ndarray:
    """Unit-area-ish outline of a random instance of ``shape``, ``[P, 2]`` (x, y)."""
    if shape == "square":
        pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    elif shape == "rectangle":
        a = rng.uniform(1.5, 3.0)
        pts = np.array([[0, 0], [a, 0], [a, 1], [0, 1]], float)
    elif shape == "circle":
        t = np.linspace(0, 2 * np.pi, 72, endpoint=False)
        pts = np.stack([1 + np.cos(t), 1 + np.sin(t)], axis=1)
    elif shape == "triangle":
        base, apex = rng.uniform(0.8, 1.6), rng.uniform(0.0, 1.0)
        pts = np.array([[0, 1], [base, 1], [apex * base, 0]], float)
    elif shape == "trapezoid":
        b1 = rng.uniform(1.0, 2.0)
        b2 = b1 * rng.uniform(0.3, 0.7)
        off = rng.uniform(0.0, b1 - b2)
        pts = np.array([[0, 1], [b1, 1], [off + b2, 0], [off, 0]], float)
    else:  # pragma: no cover - guarded by AugmentParams
        raise ValueError(shape)
    th = rng.uniform(0.0, 2.0 * np.pi)  # orientation
    c, s = math.cos(th), math.sin(th)
    pts = pts @ np.array([[c, s], [-s, c]])
    return pts - pts.min(axis=0)


def _rasterise(pts: np.ndarray, scale: float) -> np.ndarray:
    """Fill the polygon ``pts * scale`` with OpenCV (sub-pixel vertices) and crop
    to its bounding box; ``uint8`` 0/1."""
    import cv2  # imported on first use: `import jaxrecog` does not load OpenCV
    p = pts * scale
    h = int(math.ceil(p[:, 1].max())) + 2
    w = int(math.ceil(p[:, 0].max())) + 2
    canvas = np.zeros((h, w), np.uint8)
    fixed = np.round((p + 0.5) * 256).astype(np.int32)
    cv2.fillPoly(canvas, [fixed], 1, lineType=cv2.LINE_8, shift=8)
    ys, xs = np.nonzero(canvas)
    if ys.size == 0:
        return np.zeros((0, 0), np.uint8)
    return canvas[ys.min(): ys.max() + 1, xs.min(): xs.max() + 1].copy()


def make_occluder(shape: str, level: float, image_shape: tuple[int, int],
                  rng: np.random.Generator, tries: int = 20) -> np.ndarray:
    """One calibrated occluder template (``uint8`` 0/1, fits in the image) whose
    pixel count is within ``CALIBRATION_TOL`` of ``level`` times the image area."""
    H, W = image_shape
    target = level * H * W
    best, best_err = None, np.inf
    for attempt in range(tries):
        pts = _polygon(shape, rng)
        area0 = max(_rasterise(pts, 64.0).sum(), 1) / 64.0**2
        scale = math.sqrt(target / area0)
        for _ in range(8):
            t = _rasterise(pts, scale)
            n = int(t.sum())
            err = abs(n - target) / (H * W)
            if t.shape[0] <= H and t.shape[1] <= W and err < best_err:
                best, best_err = t, err
            if err <= CALIBRATION_TOL / 2 or n == 0:
                break
            scale *= math.sqrt(target / n)
        if best_err <= CALIBRATION_TOL:
            return best
    raise ValueError(
        f"cannot draw a {shape} covering {100 * level:g}% of a {H}x{W} image "
        f"within {100 * CALIBRATION_TOL:g} points (image too small?)"
    )


@dataclasses.dataclass(frozen=True)
class OccluderBank:
    """``templates[k]``: the occluder templates of level ``k`` (``[]`` for level 0),
    ``len(shapes) * n_templates`` of them; ``shape_of[k][j]`` names template j's shape."""

    levels: tuple[float, ...]
    templates: tuple[tuple[np.ndarray, ...], ...]
    shape_of: tuple[tuple[str, ...], ...]


def occluder_bank(levels: tuple[float, ...], image_shape: tuple[int, int],
                  params: AugmentParams, seed: int) -> OccluderBank:
    """Draw the calibrated occluder templates of every level (reproducible)."""
    rng = np.random.default_rng(np.random.SeedSequence((int(seed), 0x0CC1)))
    temps, names = [], []
    for lev in levels:
        t_l, n_l = [], []
        if lev > 0:
            for shape in params.shapes:
                for _ in range(params.n_templates):
                    t_l.append(make_occluder(shape, lev, image_shape, rng))
                    n_l.append(shape)
        temps.append(tuple(t_l))
        names.append(tuple(n_l))
    return OccluderBank(tuple(levels), tuple(temps), tuple(names))


# --------------------------------------------------------------------------
# per-sample random parameters
# --------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class SamplePlan:
    """Random parameters of ``B`` samples (all ``[B]``): source image, shift,
    occluder template (-1 = none) and its top-left corner, brightness offset;
    when :attr:`AugmentParams.capture` is on (else ``None``): rotation
    (degrees), scale offset ``a``, blur σ, gain grid ``[B, cells, cells]``;
    when :attr:`AugmentParams.gray_occluders` is on (else ``None``, black):
    the occluder's gray level."""

    image: np.ndarray
    dy: np.ndarray
    dx: np.ndarray
    template: np.ndarray
    y0: np.ndarray
    x0: np.ndarray
    brightness: np.ndarray
    rotation: np.ndarray | None = None
    scale: np.ndarray | None = None
    blur: np.ndarray | None = None
    gain: np.ndarray | None = None
    occluder_value: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.image.shape[0])

    def take(self, sl: slice) -> "SamplePlan":
        return SamplePlan(*(None if (v := getattr(self, f.name)) is None else v[sl]
                            for f in dataclasses.fields(self)))


def plan_rng(seed: int, camera: int, position: int, level: int) -> np.random.Generator:
    """The generator of one (camera, position, level): order-independent."""
    return np.random.default_rng(np.random.SeedSequence((int(seed), camera, position, level)))


def capture_rng(seed: int, camera: int, position: int, level: int) -> np.random.Generator:
    """The generator of the capture transforms (rotation, scale, blur, gain) of one
    (camera, position, level): separate from :func:`plan_rng`, order-independent."""
    return np.random.default_rng(np.random.SeedSequence((int(seed), camera, position, level, 2)))


def draw_plan(rng: np.random.Generator, n_images: int, params: AugmentParams,
              bank: OccluderBank, level: int, image_shape: tuple[int, int],
              capture: np.random.Generator | None = None) -> SamplePlan:
    """Parameters for ``samples_per_image`` samples of each of ``n_images`` images
    (sample ``j`` of image ``i`` is row ``i * samples_per_image + j``).

    ``capture``: the generator of the capture transforms (:func:`capture_rng`),
    needed when ``params.capture`` or ``params.gray_occluders``; it draws, in
    this order and whatever is on, rotation, scale, blur σ, gain grid and the
    occluders' gray level, so one transform's draws never depend on which
    others are on (and the gray level, drawn last, changes none of them)."""
    H, W = image_shape
    n = params.samples_per_image
    B = n_images * n
    s = params.max_shift
    image = np.repeat(np.arange(n_images), n)
    m = n if params.shared_draws else B  # draws per image (shared) or per sample
    dy = rng.integers(-s, s + 1, size=m)
    dx = rng.integers(-s, s + 1, size=m)
    brightness = rng.normal(0.0, params.brightness_sigma, size=m) if params.brightness_sigma > 0 \
        else np.zeros(m)
    temps = bank.templates[level]
    if temps:
        template = rng.integers(len(temps), size=m)
        hs = np.array([t.shape[0] for t in temps])[template]
        ws = np.array([t.shape[1] for t in temps])[template]
        y0 = np.floor(rng.random(m) * (H - hs + 1)).astype(np.int64)
        x0 = np.floor(rng.random(m) * (W - ws + 1)).astype(np.int64)
    else:
        template = np.full(m, -1)
        y0 = np.zeros(m, np.int64)
        x0 = np.zeros(m, np.int64)
    if params.shared_draws:  # row i * n + j takes draw j
        dy, dx, template, y0, x0, brightness = (np.tile(a, n_images) for a in (dy, dx, template, y0, x0, brightness))
    if not (params.capture or params.gray_occluders):
        return SamplePlan(image, dy, dx, template, y0, x0, brightness)
    if capture is None:
        raise ValueError("rotation, scale, blur, gain or gray occluders are on: draw_plan needs the capture generator")
    rotation = scale = blur = gain = value = None
    if params.capture:
        g = params.gain_cells
        rotation = capture.uniform(-1.0, 1.0, size=m) * params.max_rotation
        scale = capture.uniform(-1.0, 1.0, size=m) * params.max_scale
        lo, hi = params.blur_sigma
        blur = lo + capture.random(m) * (hi - lo)
        gain = capture.uniform(-1.0, 1.0, size=(m, g, g)) * params.gain_amplitude
        if params.shared_draws:
            rotation, scale, blur = (np.tile(a, n_images) for a in (rotation, scale, blur))
            gain = np.tile(gain, (n_images, 1, 1))
    if params.gray_occluders:
        lo, hi = params.occluder_gray
        value = lo + capture.random(m) * (hi - lo)
        if params.shared_draws:
            value = np.tile(value, n_images)
    return SamplePlan(image, dy, dx, template, y0, x0, brightness, rotation, scale, blur, gain, value)


def capture_transform(image: np.ndarray, rotation: float, scale: float, blur: float,
                      gain: np.ndarray) -> np.ndarray:
    """``g ⊙ G_σ A_{θ,a} x`` of one image (module docstring), ``float32 [H, W]``.
    Steps whose parameter is zero are skipped (so they are exact identities)."""
    import cv2  # imported on first use: `import jaxrecog` does not load OpenCV
    out = np.asarray(image, dtype=np.float32)
    H, W = out.shape
    if rotation != 0.0 or scale != 0.0:
        M = cv2.getRotationMatrix2D(((W - 1) / 2.0, (H - 1) / 2.0), float(rotation), 1.0 + float(scale))
        out = cv2.warpAffine(out, M, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if blur > 0.0:
        out = cv2.GaussianBlur(out, (0, 0), sigmaX=float(blur), sigmaY=float(blur),
                               borderType=cv2.BORDER_REPLICATE)
    if np.any(gain != 0.0):
        field = cv2.resize(np.asarray(gain, np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
        out = out * (1.0 + field)
    return out


# --------------------------------------------------------------------------
# pixel space
# --------------------------------------------------------------------------

class ShiftWindows:
    """Every integer shift of a stack of images, as a zero-copy view
    ``view[c, s - dy, s - dx] = image c shifted by (dy, dx)``, ``uint8
    [C, 2s+1, 2s+1, H, W]`` over the edge-padded images (built once, reused)."""

    def __init__(self, images: np.ndarray, max_shift: int):
        images = np.asarray(images, dtype=np.uint8)
        s = int(max_shift)
        H, W = images.shape[1:]
        self.max_shift = s
        self.padded = np.pad(images, ((0, 0), (s, s), (s, s)), mode="edge")
        self.view = np.lib.stride_tricks.sliding_window_view(self.padded, (H, W), axis=(1, 2))


def apply_geometry(images: np.ndarray | ShiftWindows, plan: SamplePlan, bank: OccluderBank, level: int,
                   max_shift: int, *, return_masks: bool = False):
    """``m ⊙ S_d x`` for every sample of ``plan``: shift then occlude, ``uint8 [B, H, W]``;
    with capture transforms in the plan (``plan.rotation`` not ``None``),
    ``m ⊙ (g ⊙ G_σ A_{θ,a} S_d x)``, ``float32 [B, H, W]`` (not rounded); with
    gray occluders (``plan.occluder_value``), ``+ (1 - m) v`` (``v`` rounded to
    an integer gray level in the ``uint8`` form).

    Shifts are vectorised through a sliding-window view of the edge-padded
    images (pass a :class:`ShiftWindows` to reuse it across batches); occluders are pasted per sample (a slice each).  With
    ``return_masks`` also returns the occluder masks ``bool [B, H, W]``.
    """
    win = images if isinstance(images, ShiftWindows) else ShiftWindows(images, max_shift)
    s = win.max_shift
    # a shift by (dy, dx) moves content down/right: out[y, x] = x[y - dy, x - dx]
    out = win.view[plan.image, s - plan.dy, s - plan.dx]  # [B, H, W] copy
    if plan.rotation is not None:
        out = np.stack([capture_transform(out[b], plan.rotation[b], plan.scale[b], plan.blur[b], plan.gain[b])
                        for b in range(len(plan))]) if len(plan) else out.astype(np.float32)
    masks = np.zeros(out.shape, bool) if return_masks else None
    temps = bank.templates[level]
    if temps:
        keep = [(1 - t).astype(out.dtype, copy=False) for t in temps]
        value = plan.occluder_value
        if value is not None and out.dtype == np.uint8:
            value = np.clip(np.round(value), 0, 255)
        for b in range(len(plan)):
            j = plan.template[b]
            t = keep[j]
            y0, x0 = plan.y0[b], plan.x0[b]
            out[b, y0: y0 + t.shape[0], x0: x0 + t.shape[1]] *= t
            if value is not None:   # keep is 0 on the occluder: add v there (no overflow)
                out[b, y0: y0 + t.shape[0], x0: x0 + t.shape[1]] += (temps[j] * value[b]).astype(out.dtype)
            if return_masks:
                masks[b, y0: y0 + t.shape[0], x0: x0 + t.shape[1]] = temps[j] > 0
    return (out, masks) if return_masks else out


def augment_images(images: np.ndarray, *, level: int, levels: tuple[float, ...],
                   params: AugmentParams = AugmentParams(), seed: int = 0,
                   camera: int = 0, position: int = 0, return_masks: bool = False):
    """Augmented 8-bit images of one camera position, in pixel space.

    ``images``: ``uint8 [C, H, W]``; returns ``uint8 [C, samples_per_image, H, W]``
    (``y`` of the module docstring, rounded and clipped to ``[0, 255]``), plus the
    occluder masks with ``return_masks``.  Uses the same plan (shift, occluder,
    brightness) as training with the same seed; training adds the pixel noise in
    feature space (:mod:`jaxrecog.train`), so only the noise draws differ.
    """
    images = np.asarray(images, dtype=np.uint8)
    C, H, W = images.shape
    bank = occluder_bank(levels, (H, W), params, seed)
    rng = plan_rng(seed, camera, position, level)
    plan = draw_plan(rng, C, params, bank, level, (H, W), capture_rng(seed, camera, position, level))
    geo, masks = apply_geometry(images, plan, bank, level, params.max_shift, return_masks=True)
    noise_rng = np.random.default_rng(np.random.SeedSequence((int(seed), camera, position, level, 1)))
    y = geo.astype(np.float32) + plan.brightness[:, None, None].astype(np.float32)
    if params.noise_sigma > 0:
        y += noise_rng.normal(0.0, params.noise_sigma, size=y.shape).astype(np.float32)
    out = np.clip(np.round(y), 0, 255).astype(np.uint8).reshape(C, -1, H, W)
    if return_masks:
        return out, masks.reshape(C, -1, H, W)
    return out
