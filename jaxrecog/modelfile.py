"""The model file: one versioned ``.npz``, written atomically, validated on load.

Layout (format version :data:`FORMAT_VERSION`): ``format_version`` (int64
scalar), ``meta`` (UTF-8 JSON as uint8 bytes: sizes, static fields, training
parameters, sha256 of the manifest, sha256 of the array contents) and per camera
``camera{i}.{mean_image,basis,eigenvalues}``, the likelihood's own arrays
``camera{i}.{name}`` for every ``name`` of its ``field_shapes`` (the diagonal
Gaussian: ``mu, var``; the full one: ``mu, var, chol``) and optionally
``camera{i}.calibration`` (all float32).  The metadata's ``likelihoods`` lists
each camera's kind (:data:`jaxrecog.kernels.LIKELIHOODS`); ``covariance``, the
older single entry (``"diag"`` / ``"full"``), is still written and is what
files without ``likelihoods`` are read by.  Version 2 added the optional
``calibration`` ``[V, L]`` variance factors (:mod:`jaxrecog.calibration`) and
the ``calibration`` metadata entry; version-1 files still load, as
uncalibrated models, with a :class:`ModelFileVersionWarning`.  Version 3 added
the likelihood families with parameters of their own beside the Gaussians'
(``student-t``: ``mu, scale2, nu``; ``gaussian-lowrank``: ``mu, W, psi``, the
rank being ``W``'s last axis), the training metadata's ``likelihood_options``
and the calibration metadata's ``shape`` offsets (:mod:`jaxrecog.calibration`):
an older reader stops at the version instead of at an unknown kind.  A
version-2 file is a valid version-3 file (Gaussians only) and loads as it is,
without a warning.  Version 4 added the ``recipe`` metadata entry
(:mod:`jaxrecog.recipes`: how the model was trained and its stop rule);
files of versions 2 and 3 load as they are and report recipe ``thesis``
(:func:`jaxrecog.recipes.recipe_from_meta`).  Every likelihood parameter is checked on load (finite,
and the family's ``problems()``: e.g. ``nu <= 2``, a non-positive variance, a
rank larger than K), each failure one line naming the field.

Saving writes a temporary file in the target folder, fsyncs it, then
``os.replace``s it over the target (and fsyncs the folder): a crash at any
moment leaves either the old or the new file, never a broken one.  The
target must be absent or a regular file, in a folder that exists: a folder,
``/dev/null``, ``/dev/full`` or a FIFO is refused, and no missing folder is
created (:func:`jaxrecog._files.check_output_file`).  The
temporary file is ``.NAME.HOST-PID.RANDOM.tmp``: one left by a writer that
was killed (SIGKILL, power loss) is removed by the next save of that name
once its process is gone.  A new model file gets the mode of any newly
created file (``0666`` less the umask); one written over an existing file
keeps that file's mode.  :func:`check_writable` tells before a long training
whether the file can be written at all.  Loading
raises one :class:`ModelFileError` subclass per failure, each with a one-line
message naming the file.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import secrets
import socket
import time
import warnings
import zipfile
import zlib
from pathlib import Path

import jax
import numpy as np

from ._files import check_output_file, replace_from_temp
from .problems import one_line, problem_message
from .kernels import likelihood_class
from .recipes import THESIS
from .sensor_model import CameraModel, SensorModel, model_problems

__all__ = [
    "FORMAT_VERSION",
    "ModelFileError",
    "ModelFileMissingError",
    "ModelFileCorruptError",
    "ModelFileTruncatedError",
    "ModelFileVersionError",
    "ModelFileContentError",
    "ModelFileVersionWarning",
    "save_model",
    "check_writable",
    "load_model",
    "load_model_meta",
]

FORMAT_VERSION = 4
_OLD_VERSIONS = (1,)  # still read, as uncalibrated models, with a warning
_SAME_VERSIONS = (2, 3)  # read as they are: subsets of version 4 (no recipe entry: recipe 'thesis')
_EIGEN = {"mean_image": "V D", "basis": "V D K", "eigenvalues": "V K"}   # every camera, before its likelihood
_CALIBRATION = {"calibration": "V L"}


class ModelFileError(Exception):
    """A model file cannot be loaded."""


class ModelFileMissingError(ModelFileError, FileNotFoundError):
    """No file at the path."""


class ModelFileCorruptError(ModelFileError):
    """The bytes are damaged (not a zip, bad CRC, checksum mismatch, bad metadata)."""


class ModelFileTruncatedError(ModelFileError):
    """The file ends early (a zip whose end record is missing)."""


class ModelFileVersionError(ModelFileError):
    """The file's format version is not the one this code reads."""


class ModelFileContentError(ModelFileError):
    """Arrays missing, of the wrong shape or dtype, or non-finite / non-positive."""


class ModelFileVersionWarning(UserWarning):
    """A model file of an older, still readable format version was loaded
    (version 1: no calibration, the model loads uncalibrated)."""


def _arrays(model: SensorModel) -> dict[str, np.ndarray]:
    out = {}
    for i, cam in enumerate(model.cameras):
        fields = {**{f: getattr(cam, f) for f in _EIGEN}, **cam.likelihood.arrays(),
                  "calibration": cam.calibration}
        for f, x in fields.items():
            if x is not None:
                out[f"camera{i}.{f}"] = np.asarray(x, dtype=np.float32)
    return out


def _content_hash(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for k in sorted(arrays):
        h.update(k.encode())
        h.update(str(arrays[k].shape).encode())
        h.update(np.ascontiguousarray(arrays[k]).tobytes())
    return h.hexdigest()


def save_model(path: str | os.PathLike, model: SensorModel, *, training: dict | None = None,
               manifest_sha256: str | None = None, calibration: dict | None = None,
               recipe: dict | None = None) -> Path:
    """Write ``model`` to ``path`` atomically (temp file + fsync + ``os.replace``).

    ``training`` (JSON-serialisable parameters) and ``manifest_sha256`` are
    stored as provenance (see :class:`~jaxrecog.train.TrainingInfo`);
    ``calibration`` (JSON-serialisable, e.g.
    :meth:`jaxrecog.calibration.CalibrationInfo.to_dict`) likewise.  The
    calibration factors themselves are arrays of the model.  ``recipe``
    (:meth:`jaxrecog.recipes.Recipe.to_dict`) is the recipe the model was
    trained by; ``None`` records ``thesis``.
    """
    path = Path(path)
    arrays = _arrays(model)
    meta = {
        "format_version": FORMAT_VERSION,
        "n_cameras": model.n_cameras,
        "positions": list(model.positions),
        "n_objects": model.n_objects,
        "n_poses": model.n_poses,
        "levels": list(model.levels),
        "image_shape": list(model.image_shape),
        "covariance": model.covariance,
        "likelihoods": list(model.likelihood_kinds),
        "n_components": model.n_components,
        "training": training or {},
        "calibrated": any(c.calibration is not None for c in model.cameras),
        "calibration": calibration or {},
        "recipe": recipe if recipe is not None else THESIS.to_dict(),
        "stability": model.stability,
        "manifest_sha256": manifest_sha256,
        "content_sha256": _content_hash(arrays),
    }
    payload = {
        "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
        "meta": np.frombuffer(json.dumps(meta, sort_keys=True).encode(), dtype=np.uint8),
        **arrays,
    }
    check_output_file(path, "model file")  # a regular file in a folder that exists, never /dev/null or a FIFO
    folder = path.parent if str(path.parent) else Path(".")
    _remove_stale_temps(folder, path.name)
    fd, tmp = _create_temp(folder, path.name)
    replace_from_temp(fd, tmp, path, lambda f: np.savez(f, **payload), durable=True)
    try:  # make the rename itself durable
        dfd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass
    return path


def _host_tag() -> str:
    return re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())[:32] or "host"


#: a temporary file of ours: ``.NAME.HOST-PID.RANDOM.tmp``
_TEMP = re.compile(r"(?P<host>[A-Za-z0-9-]+)-(?P<pid>[0-9]+)\.[A-Za-z0-9_]+\.tmp")
#: a temporary file of an older writer (``tempfile.mkstemp``, no PID): removed once this old
_OLD_TEMP = re.compile(r"[A-Za-z0-9_]{8}\.tmp")
_OLD_TEMP_AGE_S = 3600.0


def _create_temp(folder: Path, name: str) -> tuple[int, str]:
    """A new temporary file for ``name`` in ``folder``, created exclusively
    (never through a link) with mode ``0666`` less the umask."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        tmp = folder / f".{name}.{_host_tag()}-{os.getpid()}.{secrets.token_hex(4)}.tmp"
        try:
            return os.open(tmp, flags, 0o666), str(tmp)
        except FileExistsError:
            continue
    raise FileExistsError(f"cannot create a temporary file for {name} in {folder}")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def _remove_stale_temps(folder: Path, name: str) -> None:
    """Remove the temporary files of ``name`` left by a writer of this host
    that is gone (killed mid-write), and those of older writers (no PID in
    the name) after :data:`_OLD_TEMP_AGE_S`; a live writer's file stays."""
    prefix = f".{name}."
    try:
        entries = [e for e in os.scandir(folder) if e.name.startswith(prefix) and e.name.endswith(".tmp")]
    except OSError:
        return
    host = _host_tag()
    for e in entries:
        rest = e.name[len(prefix):]
        m = _TEMP.fullmatch(rest)
        try:
            if m:
                if m["host"] != host or _alive(int(m["pid"])):
                    continue
            elif not (_OLD_TEMP.fullmatch(rest) and time.time() - e.stat(follow_symlinks=False).st_mtime > _OLD_TEMP_AGE_S):
                continue
            if e.is_file(follow_symlinks=False):
                os.unlink(e.path)
        except OSError:
            pass


def check_writable(path: str | os.PathLike) -> None:
    """Raise a one-line :class:`OSError` unless :func:`save_model` could write
    ``path``: its folder exists and takes a new file (tried with a temporary
    file removed at once), and ``path`` is absent or a regular file (not a
    folder, ``/dev/null``, a FIFO: :func:`jaxrecog._files.check_output_file`).
    Nothing is left behind.  For a command to call before it spends minutes
    training."""
    path = check_output_file(path, "model file")
    folder = path.parent if str(path.parent) else Path(".")
    try:
        fd, tmp = _create_temp(folder, path.name)
    except OSError as e:
        raise type(e)(f"cannot write model file {path}: folder {folder} is not writable "
                      f"({e.strerror or e})") from None
    os.close(fd)
    os.unlink(tmp)


def _open(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise ModelFileMissingError(f"model file {path}: no such file")
    with open(path, "rb") as f:
        head = f.read(4)
    if head != b"PK\x03\x04":
        raise ModelFileCorruptError(f"model file {path}: not a model file (no .npz/zip header)")
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile:
        raise ModelFileTruncatedError(
            f"model file {path}: truncated (zip end record missing; interrupted copy or write?)"
        ) from None
    try:
        with zf:
            _check_members(path, zf)
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, NotImplementedError, RuntimeError, zlib.error) as e:
        if isinstance(e, ModelFileError):
            raise
        raise ModelFileCorruptError(f"model file {path}: damaged content ({type(e).__name__}: {one_line(e)})") from None
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    # NotImplementedError: an unknown compression method; RuntimeError: the
    # "encrypted" flag; zlib.error: a damaged deflate stream (bit flips)
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError, NotImplementedError,
            RuntimeError, zlib.error) as e:
        kind = type(e).__name__
        raise ModelFileCorruptError(f"model file {path}: damaged content ({kind}: {one_line(e)})") from None


#: The most a model file's members may inflate to, in all, per byte of the
#: file (a model is stored uncompressed: about 1) and at most (bytes).
MAX_INFLATION = 64
MAX_MODEL_BYTES = 1 << 34


def _size(n: int) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n} bytes" if unit == "bytes" else f"{n:.2f} {unit}"
        n /= 1024
    return f"{n}"


def _check_members(path: Path, zf: zipfile.ZipFile) -> None:
    """Refuse a decompression bomb before anything is inflated: the members'
    declared sizes (zip headers) in all at most :data:`MAX_INFLATION` times
    the file's size and :data:`MAX_MODEL_BYTES`; each ``.npy`` member's own
    header (shape, dtype: read from its first bytes only) a plain numeric
    array whose size is exactly what the zip header declares.  Raises
    :class:`ModelFileCorruptError` naming the file (and the member)."""
    infos = zf.infolist()
    declared = sum(i.file_size for i in infos)
    on_disk = path.stat().st_size
    limit = min(MAX_MODEL_BYTES, MAX_INFLATION * on_disk + (1 << 20))
    if declared > limit:
        raise ModelFileCorruptError(f"model file {path}: its members declare {_size(declared)} in all, "
                                    f"more than a {_size(on_disk)} model file may hold ({_size(limit)}): "
                                    f"not a model file (a decompression bomb?)")
    for info in infos:
        name = one_line(info.filename.removesuffix(".npy"), 80)
        with zf.open(info) as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, _, dtype = np.lib.format.read_array_header_2_0(f)
            else:
                raise ModelFileCorruptError(f"model file {path}: array {name} has .npy format version "
                                            f"{version}, not 1.0 or 2.0")
            header = f.tell()
        if dtype.hasobject or dtype.itemsize == 0:
            raise ModelFileCorruptError(f"model file {path}: array {name} has dtype {dtype}, not a number type")
        nbytes = math.prod(int(n) for n in shape) * dtype.itemsize
        if header + nbytes != info.file_size:
            raise ModelFileCorruptError(
                f"model file {path}: array {name} declares shape {tuple(shape)} {dtype} ({_size(nbytes)}) but "
                f"the file holds {_size(max(info.file_size - header, 0))} of it")


def load_model_meta(path: str | os.PathLike) -> dict:
    """The metadata dict of a model file (after the version check)."""
    return _read(Path(path))[1]


def _read(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    data = _open(path)
    if "format_version" not in data:
        raise ModelFileCorruptError(f"model file {path}: no format_version entry")
    v = np.asarray(data["format_version"])
    if v.size != 1 or not np.issubdtype(v.dtype, np.integer):
        raise ModelFileCorruptError(f"model file {path}: format_version is not one integer "
                                    f"({v.dtype} of shape {v.shape})")
    version = int(v.reshape(-1)[0])
    if version in _OLD_VERSIONS:
        warnings.warn(
            f"model file {path}: format version {version} (older than {FORMAT_VERSION}); "
            f"loaded as an uncalibrated model", ModelFileVersionWarning, stacklevel=3,
        )
    elif version != FORMAT_VERSION and version not in _SAME_VERSIONS:
        raise ModelFileVersionError(
            f"model file {path}: format version {version}, this jaxrecog reads version "
            f"{FORMAT_VERSION} (retrain or convert the model)"
        )
    try:
        meta = json.loads(bytes(data["meta"]).decode())
    except (KeyError, ValueError, RecursionError) as e:  # RecursionError: absurdly nested JSON
        raise ModelFileCorruptError(f"model file {path}: unreadable metadata ({one_line(e)})") from None
    if not isinstance(meta, dict):
        raise ModelFileCorruptError(f"model file {path}: metadata is a JSON {type(meta).__name__}, not an object")
    meta["format_version"] = version
    arrays = {k: v for k, v in data.items() if k not in ("format_version", "meta")}
    if _content_hash(arrays) != meta.get("content_sha256"):
        raise ModelFileCorruptError(f"model file {path}: array checksum mismatch (damaged content)")
    return arrays, meta


def load_model(path: str | os.PathLike) -> SensorModel:
    """Load and validate a model file (version, shapes, dtypes, finiteness).

    Raises:
        ModelFileMissingError, ModelFileCorruptError, ModelFileTruncatedError,
        ModelFileVersionError, ModelFileContentError: one line naming the file
        (unexpected arrays: their count, then the first ten one per line).
        Nothing else comes out, whatever the bytes (``tests/test_fuzz_loaders.py``).
    """
    path = Path(path)
    arrays, meta = _read(path)

    def bad(msg: str):
        return ModelFileContentError(f"model file {path}: {one_line(msg)}")

    try:
        n_cam = int(meta["n_cameras"])
        positions = [int(v) for v in meta["positions"]]
        n_objects, n_poses = int(meta["n_objects"]), int(meta["n_poses"])
        levels = tuple(float(x) for x in meta["levels"])
        H, W = (int(x) for x in meta["image_shape"])
        K = int(meta["n_components"])
        kinds = meta.get("likelihoods")           # per camera; files before it: "covariance"
        kinds = None if kinds is None else [str(k) for k in kinds]
        common = str(meta["covariance"]) if kinds is None else None
        stability = meta.get("stability")       # files before it: None (not fitted)
        if stability is not None and (isinstance(stability, bool) or not isinstance(stability, (int, float))):
            raise TypeError(f"stability {stability!r} is not a number")
        stability = None if stability is None else float(stability)
    except (KeyError, TypeError, ValueError, OverflowError) as e:  # OverflowError: int(Infinity)
        raise bad(f"metadata lacks a valid field ({type(e).__name__}: {e})") from None
    if stability is not None and not (0.0 <= stability < math.inf):
        raise bad(f"stability {stability} must be a finite number >= 0")
    C, L = n_objects * n_poses, len(levels)
    counts = (n_cam, *positions, n_objects, n_poses, L, H, W, K)
    if len(positions) != n_cam or min(counts) < 1 or (kinds is not None and len(kinds) != n_cam):
        raise bad(f"inconsistent metadata ({n_cam} camera(s), positions {positions}, likelihoods "
                  f"{kinds or common}, {n_objects} objects x {n_poses} poses, {L} levels, image {H}x{W}, K {K})")
    kinds = kinds or [common] * n_cam
    if not all(0.0 <= lv < 1.0 for lv in levels):
        raise bad(f"occlusion levels {levels} must be fractions in [0, 1)")
    cameras = []
    known = set()
    for i, (V, kind) in enumerate(zip(positions, kinds)):
        try:
            family = likelihood_class(kind)
        except ValueError as e:
            raise bad(f"camera {i}: {e}") from None
        specs = {**_EIGEN, **family.field_shapes}
        if f"camera{i}.calibration" in arrays and meta["format_version"] >= 2:
            specs.update(_CALIBRATION)
        sizes = {"V": V, "C": C, "L": L, "K": K, "D": H * W}
        fields = {f: _checked(arrays, f"camera{i}.{f}", spec, sizes, bad) for f, spec in specs.items()}
        known |= {f"camera{i}.{f}" for f in specs}
        # device_put, not jnp.asarray: jax (0.10) compiles a program per array shape for
        # asarray of a NumPy array, eight per camera here, where device_put only copies
        lik = family.from_arrays({f: jax.device_put(fields[f]) for f in family.field_shapes})
        for f, problem in lik.problems():
            raise bad(f"camera{i}.{f} {problem}")
        if "calibration" in fields and np.any(fields["calibration"] <= 0):
            raise bad(f"camera{i}.calibration has non-positive factors")
        cal = jax.device_put(fields["calibration"]) if "calibration" in fields else None
        cameras.append(CameraModel(*(jax.device_put(fields[f]) for f in _EIGEN), calibration=cal, likelihood=lik))
    extra = set(arrays) - known
    if extra:
        names = [one_line(k) for k in sorted(extra)]
        err = ModelFileContentError(f"model file {path}: " + problem_message("unexpected arrays", names))
        err.problems = names  # all of them, for --debug
        raise err
    return _explaining(SensorModel(
        cameras=tuple(cameras),
        n_objects=n_objects,
        n_poses=n_poses,
        levels=levels,
        image_shape=(H, W),
        stability=stability,
    ), path)


def _explaining(model: SensorModel, path: Path) -> SensorModel:
    """``model`` if it can explain a capture at all
    (:func:`~jaxrecog.sensor_model.model_problems`: an orthonormal basis, a
    unit mean, bounded feature means, finite positive variances), else a
    :class:`ModelFileContentError` naming the file and the first problem."""
    problems = model_problems(model)
    if problems:
        raise ModelFileContentError(f"model file {path}: {one_line(problems[0])}"
                                    + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""))
    return model


def _checked(arrays: dict[str, np.ndarray], key: str, spec: str, sizes: dict[str, int], bad) -> np.ndarray:
    """``arrays[key]``, checked: present, float32, shape ``spec`` (axis names;
    a name not in ``sizes`` is bound by its first occurrence), finite."""
    if key not in arrays:
        raise bad(f"missing array {key}")
    x = arrays[key]
    if x.dtype != np.float32:
        raise bad(f"{key} has dtype {x.dtype}, expected float32")
    axes = spec.split()
    if x.ndim == len(axes):
        for a, n in zip(axes, x.shape):
            sizes.setdefault(a, n)
    shape = tuple(sizes.get(a, "?") for a in axes)
    if x.shape != shape:
        raise bad(f"{key} has shape {x.shape}, expected {shape}".replace("'?'", "?"))
    if not np.all(np.isfinite(x)):
        raise bad(f"{key} contains NaN or infinite values")
    return x
