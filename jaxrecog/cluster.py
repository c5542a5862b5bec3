"""Campaigns and renders on a Ray cluster: the ``--cluster`` option.

``--cluster ray`` starts a local Ray instance (or joins the one
``RAY_ADDRESS`` names); ``--cluster ray://HOST:PORT`` joins a running cluster
through its Ray Client server.  Then (``docs/cluster.md``):

- a campaign's rigs live in Ray actors (:class:`jaxrecog.ray_rigs.RayRigs`,
  the same pool interface as :class:`~jaxrecog.hardware.rigs.rig_pool.ProcessRigs`),
  one actor per CPU of the cluster (or ``Settings.render_workers``);
- its trials go out in batches, one actor call each, that run the ordinary
  trial driver (:func:`jaxrecog.driver.run_trials`) next to the rigs; the
  recognizer (model and planner tables) is put into Ray's object store once
  per campaign and read once per actor;
- finished trials stream back one by one into the same resumable trial
  store (:class:`~jaxrecog.results.TrialStore`) as a local campaign's;
- rendering an image database (:mod:`jaxrecog.ray_render`) splits it by
  (object, pose) into Ray tasks that return their PNG files.

A trial's result depends only on its spec, the key and the seed (the rig is
reseeded per capture with ``(seed, trial, step)``, the recognizer's key is
folded with ``(trial, step)``), so a campaign on the cluster gives the same
trials and results as in one process, bit for bit (tested), and a worker lost
mid-run costs only the trials it had not finished: they are run again
elsewhere, and a finished trial is never run or stored twice.

This module imports nothing of Ray: ``import jaxrecog`` stays light and a
cluster spec is checked (``Settings.cluster``) without Ray installed.  The
modules that use Ray (:mod:`jaxrecog.ray_rigs`, :mod:`jaxrecog.ray_render`)
are imported only when a cluster is used.
"""

from __future__ import annotations

import os
import re
import socket
import sys
import threading
import warnings
from typing import Any

from .problems import one_line

__all__ = ["ClusterError", "RAY_INSTALL", "PROBE_TIMEOUT_S", "CONNECT_TIMEOUT_S", "check_cluster", "connect", "import_ray",
           "version_problems", "ray_error_line"]

#: What to install for ``--cluster`` (the ``cluster`` extra of pyproject.toml).
RAY_INSTALL = "pip install 'jaxrecog[cluster]'"
#: Seconds :func:`connect` waits for the head node's port to take a connection:
#: a cluster that is not there is one line within this (plus Python's start-up).
PROBE_TIMEOUT_S = 5.0
#: Seconds :func:`connect` then waits for Ray to join: a Ray Client server
#: starts a process per client (measured ~10-20 s on a loaded 2-core machine).
CONNECT_TIMEOUT_S = 120.0


class ClusterError(RuntimeError):
    """The cluster cannot be reached or used (one line saying why)."""


def check_cluster(spec: str | None) -> str | None:
    """``spec`` normalised: ``None`` (or ``""``) = no cluster, ``"ray"`` = a
    local Ray instance, ``"ray://HOST:PORT"`` = a running cluster's Ray
    Client server; anything else is a :class:`ValueError` naming the forms."""
    if spec is None or spec == "":
        return None
    if not isinstance(spec, str):
        raise ValueError(f"cluster must be 'ray' or 'ray://HOST:PORT', got {one_line(repr(spec), 80)}")
    s = spec.strip()
    if s == "ray":
        return s
    if s.startswith("ray://"):
        _host_port(s)
        return s
    raise ValueError(f"cluster must be 'ray' (a local Ray instance) or 'ray://HOST:PORT' (a running cluster), "
                     f"got {one_line(repr(spec), 80)}")


def _host_port(spec: str) -> tuple[str, int]:
    rest = spec[len("ray://"):]
    host, sep, port = rest.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"cluster {one_line(repr(spec), 80)}: expected ray://HOST:PORT with a port in 1..65535 "
                         "(the head node's Ray Client port, 10001 by default)")
    return host.strip("[]"), int(port)


def _probe(host: str, port: int, timeout: float) -> None:
    """Open and close one TCP connection to ``host:port``: a cluster that is
    not there fails here at once (or after ``timeout``), not after Ray
    Client's minutes of retries."""
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except socket.gaierror as e:
        raise ClusterError(f"cannot reach the Ray cluster at ray://{host}:{port}: unknown host "
                           f"({e.strerror or e})") from None
    except TimeoutError:
        raise ClusterError(f"cannot reach the Ray cluster at ray://{host}:{port}: no answer within "
                           f"{timeout:g} s") from None
    except OSError as e:
        raise ClusterError(f"cannot reach the Ray cluster at ray://{host}:{port}: "
                           f"{(e.strerror or str(e)).lower()} (is its head node running `ray start --head`?)") from None


def ray_error_line(err: BaseException, spec: str) -> str:
    """One line for an error of ``ray.init``: Ray's multi-line version
    mismatch report becomes "Ray version mismatch: the cluster runs Ray X
    (Python Y), this process Ray Z (Python W)"; anything else its first line."""
    text = str(err)
    pairs = re.findall(r"Ray: (\S+)\s+Python: (\S+)", text)
    if "Version mismatch" in text and len(pairs) == 2:
        (cr, cp), (hr, hp) = pairs  # Ray's report: the cluster's versions, then this process's
        return (f"Ray version mismatch with {spec}: the cluster runs Ray {cr} (Python {cp}), this process "
                f"Ray {hr} (Python {hp}); install the cluster's versions here")
    first = next((ln.strip() for ln in text.splitlines() if ln.strip()), type(err).__name__)
    hint = ""
    if "client connection timeout" in text and os.environ.get("RAY_AUTH_MODE") != "token":
        # a Ray Client server that wants a token times out without saying so
        hint = (" (does the cluster use Ray's token authentication? then set RAY_AUTH_MODE=token and put its "
                "token, `ray get-auth-token` on the head node, in ~/.ray/auth_token)")
    return f"cannot use the Ray cluster {spec}: {one_line(first, 200)}{hint}"


def import_ray():
    """The ``ray`` module, or a one-line :class:`ClusterError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ClusterError(f"--cluster needs Ray, which is not installed: {RAY_INSTALL}") from None
    return ray


def connect(spec: str, *, timeout: float = CONNECT_TIMEOUT_S, num_cpus: int | None = None):
    """Make sure this process is connected to the cluster ``spec`` (see
    :func:`check_cluster`) and return the ``ray`` module.

    A process already connected (``ray.is_initialized()``: a script's or a
    test's own ``ray.init``) keeps its connection.  ``ray`` starts a local
    instance (``num_cpus``: its CPUs, default all) without the dashboard;
    ``ray://HOST:PORT`` first checks that the port takes a connection (within
    :data:`PROBE_TIMEOUT_S`: a cluster that is not there fails at once), then
    joins.  Errors are one line, a :class:`ClusterError`; joining gives up
    after ``timeout`` seconds (the attempt runs in a helper thread,
    abandoned then; a local instance starts in this thread)."""
    spec = check_cluster(spec)
    if spec is None:
        raise ValueError("connect() needs a cluster: 'ray' or 'ray://HOST:PORT'")
    ray = import_ray()
    address = None if spec == "ray" else spec
    if address is not None:
        _probe(*_host_port(spec), timeout=min(timeout, PROBE_TIMEOUT_S))
    if ray.is_initialized():
        return ray
    kw: dict[str, Any] = dict(logging_level="ERROR", log_to_driver=False)
    if address is None:
        # "local": a new instance, not the last `ray start` of this machine (its
        # address file outlives a head stopped by a signal); RAY_ADDRESS, given on purpose, is joined
        address = os.environ.get("RAY_ADDRESS") or "local"
        kw.update(include_dashboard=False, num_cpus=None if address != "local" else num_cpus)
    outcome: list = []

    def attempt():
        try:
            with warnings.catch_warnings():  # JAX's warning at a fork: Ray's services fork and exec at once
                warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
                ray.init(address=address, **kw)
            outcome.append(None)
        except BaseException as e:  # noqa: BLE001 -- reported by the caller's thread
            outcome.append(e)

    if address == "local":
        # here, not in a helper thread: Ray's services get a signal to die
        # when the *thread* that started them ends (prctl PDEATHSIG); nothing to wait for either
        attempt()
    else:
        worker = threading.Thread(target=attempt, daemon=True, name="jaxrecog-ray-connect")
        worker.start()
        worker.join(timeout)
    if not outcome:
        if spec != "ray":
            why = (f"{spec} took the connection but no Ray cluster answered within {timeout:g} s (is it a Ray "
                   "Client server? the head node's listens on port 10001 by default)")
        elif address != "local":
            why = f"no Ray cluster answered at RAY_ADDRESS={address} within {timeout:g} s"
        else:
            why = f"the local Ray instance did not start within {timeout:g} s"
        raise ClusterError(why)
    if outcome[0] is not None:
        raise ClusterError(ray_error_line(outcome[0], spec)) from None
    return ray


def local_versions() -> dict[str, str]:
    """The versions a worker must share with the driver: Python (major.minor),
    Ray, JAX and jaxrecog."""
    import jax
    import ray

    from . import __version__

    return {"Python": ".".join(map(str, sys.version_info[:2])), "Ray": ray.__version__, "JAX": jax.__version__,
            "jaxrecog": __version__}


def version_problems(here: dict[str, str], there: dict[str, str], where: str) -> str | None:
    """One line naming every version that differs between this process
    (``here``) and a worker (``there``, at ``where``), or ``None``."""
    diff = [f"{k} {there.get(k, '?')} there, {v} here" for k, v in here.items() if there.get(k) != v]
    if not diff:
        return None
    head = "Ray version mismatch" if any(d.startswith("Ray ") for d in diff) else "version mismatch"
    return f"{head} on the cluster's worker {where}: {'; '.join(diff)} (install the same versions on every node)"

