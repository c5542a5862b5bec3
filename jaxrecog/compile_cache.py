"""The persistent XLA compilation cache: compiled programs kept on disk, so
that the next process with the same programs loads them instead of
compiling them again (``jaxrecog plan`` on the demo model: ~6 s cold,
~2-3 s warm on two CPU cores; most of a short command is compilation).

Where: ``$JAXRECOG_COMPILE_CACHE`` when it names a folder, otherwise
``$XDG_CACHE_HOME/jaxrecog/jax`` (``~/.cache/jaxrecog/jax``), and inside it
one folder per version tag ``jaxrecog-V-jax-V-jaxlib-V``: an upgrade of
any of the three starts an empty folder and never reads another version's
programs.  Within a folder JAX keys each entry by the program (its HLO), the
compile options, the XLA flags and the backend, so a changed model (other
shapes, other constants) is a new entry, never a stale one.  Deleting the
folder clears the cache.

Off: ``JAXRECOG_COMPILE_CACHE=0`` (or ``off``, ``false``, ``no``), the CLI's
``--no-compile-cache``, ``compile_cache = false`` in a settings file's
``[global]`` table, or :func:`configure` ``(False)``.  A cache folder that
JAX was given by its own settings (``JAX_COMPILATION_CACHE_DIR``,
``jax.config``) is left as it is unless jaxrecog is told a folder.

Two processes may share a folder: an entry is written to a temporary file
and renamed into place, so a reader sees a whole entry or none (JAX's own
writer, as of 0.10, writes the file in place, and a process that reads it
meanwhile reads a partial program).  A folder that cannot be written (read
only, a full disk) costs one warning and the command runs on, compiling.
"""

from __future__ import annotations

import functools
import os
import tempfile
import warnings
from collections.abc import Mapping
from pathlib import Path

__all__ = ["ENV", "CompileCacheWarning", "configure", "default_folder", "ensure", "version_tag"]

#: The environment variable: ``0`` / ``off`` turns the cache off, a path moves it.
ENV = "JAXRECOG_COMPILE_CACHE"
_OFF = {"0", "off", "false", "no", "none"}


class CompileCacheWarning(UserWarning):
    """The compilation cache folder cannot be used; programs are compiled as without one."""


def version_tag() -> str:
    """``jaxrecog-V-jax-V-jaxlib-V``: the versions whose programs a folder holds."""
    import jax
    import jaxlib

    from ._version import __version__
    return f"jaxrecog-{__version__}-jax-{jax.__version__}-jaxlib-{jaxlib.__version__}"


def default_folder(env: Mapping[str, str] | None = None) -> Path | None:
    """The cache folder the settings give (``None``: off): ``$JAXRECOG_COMPILE_CACHE``
    (a path, or ``0`` for off), else ``$XDG_CACHE_HOME/jaxrecog/jax``, else
    ``~/.cache/jaxrecog/jax``; with :func:`version_tag` appended."""
    env = os.environ if env is None else env
    given = env.get(ENV, "").strip()
    if given.lower() in _OFF:
        return None
    if given:
        root = Path(given).expanduser()
    else:
        base = env.get("XDG_CACHE_HOME") or str(Path("~/.cache").expanduser())
        root = Path(base) / "jaxrecog" / "jax"
    return root / version_tag()


#: what this process set up: None before the first call, then the folder (or False: off)
_state: dict[str, object] = {}


def configure(folder: str | os.PathLike | bool | None = None) -> Path | None:
    """Point JAX's persistent compilation cache at ``folder`` (``None``: the
    settings' folder, :func:`default_folder`; ``False``: no cache at all, JAX's
    own settings included), with no minimum compile time or entry size (a
    CPU compiles even a one-op program in ~60 ms; a hit costs ~10 ms).
    Returns the folder in use, or ``None``.  A folder given explicitly is used
    as it is (no version tag appended).  A folder that cannot be written: one
    :class:`CompileCacheWarning`, and no cache."""
    import jax

    if folder is False or (folder is None and os.environ.get(ENV, "").strip().lower() in _OFF):
        jax.config.update("jax_enable_compilation_cache", False)
        _state["folder"] = False
        return None
    if folder is None or folder is True:
        theirs = jax.config.jax_compilation_cache_dir
        if theirs and theirs != str(_state.get("folder")) and not os.environ.get(ENV, "").strip():
            _state["folder"] = Path(theirs)   # JAX's own settings name a folder: theirs
            _install_atomic_writes()
            return Path(theirs)
        path = default_folder()
    else:
        path = Path(folder).expanduser()
    problem = _unusable(path)
    if problem:
        warnings.warn(f"compilation cache {path} not usable ({problem}); compiling without it",
                      CompileCacheWarning, stacklevel=2)
        jax.config.update("jax_enable_compilation_cache", False)
        _state["folder"] = False
        return None
    _install_atomic_writes()
    changed = jax.config.jax_compilation_cache_dir != str(path)
    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    if changed:  # JAX looks the folder up once, at the first compilation: look again
        from jax.experimental.compilation_cache import compilation_cache
        compilation_cache.reset_cache()
    _state["folder"] = path
    return path


def ensure() -> Path | None:
    """:func:`configure` from the settings, once per process (what the library's
    entry points call; a later explicit :func:`configure` still wins)."""
    if "folder" not in _state:
        configure()
    folder = _state["folder"]
    return folder if isinstance(folder, Path) else None


def _unusable(path: Path) -> str | None:
    """Why ``path`` cannot hold the cache (``None``: it can): it cannot be
    made, or a file cannot be written in it."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=path, prefix=".probe-")
        try:
            os.write(fd, b"x" * 4096)
        finally:
            os.close(fd)
            os.unlink(probe)
    except OSError as e:
        return e.strerror or type(e).__name__
    return None


def _install_atomic_writes() -> None:
    """Make JAX's file cache write each entry to a temporary file and rename it
    into place (readers never see a partial program), and, where the folder
    stops taking writes (a full disk), warn once and stop writing instead of
    warning at every compilation.  Done through JAX's ``get_file_cache``
    (internal; where a JAX version lacks it, JAX's own writer is used)."""
    try:
        from jax._src import compilation_cache as cc
        from jax._src import lru_cache
    except ImportError:
        return
    if getattr(cc.get_file_cache, "_jaxrecog_atomic", False) or not hasattr(lru_cache, "LRUCache"):
        return
    base_get_file_cache = cc.get_file_cache

    def get_file_cache(path: str):
        found = base_get_file_cache(path)
        if found is None or type(found[0]) is not lru_cache.LRUCache or found[0].eviction_enabled \
                or "://" in str(path):
            return found  # a size cap (JAX's locked cache), a verifying cache, a remote folder
        return atomic_file_cache()(path, max_size=-1), found[1]

    get_file_cache._jaxrecog_atomic = True  # type: ignore[attr-defined]
    cc.get_file_cache = get_file_cache


@functools.cache
def atomic_file_cache() -> type:
    """JAX's unbounded file cache (``LRUCache`` without a size cap) with
    whole-file writes: temporary file, then ``os.replace``; a failed write
    warns once per process and turns writing off."""
    from jax._src import lru_cache

    suffix = getattr(lru_cache, "_CACHE_SUFFIX", "-cache")

    class AtomicFileCache(lru_cache.LRUCache):
        failed = False

        def put(self, key: str, value: bytes) -> None:
            if AtomicFileCache.failed:
                return
            final = self.path / f"{key}{suffix}"
            try:
                if final.exists():
                    return
                fd, tmp = tempfile.mkstemp(dir=self.path, prefix=f".{key}.", suffix=".tmp")
                try:
                    with os.fdopen(fd, "wb") as f:
                        f.write(value)
                    os.replace(tmp, final)
                except BaseException:
                    Path(tmp).unlink(missing_ok=True)
                    raise
            except OSError as e:
                AtomicFileCache.failed = True
                warnings.warn(f"compilation cache {self.path}: cannot write ({e.strerror or e}); "
                              "compiled programs are no longer saved in this process", CompileCacheWarning)

    return AtomicFileCache
