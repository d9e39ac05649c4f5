"""Ray, the optional engine of the distributed backends (``--backend ray``).

Ray is an optional dependency (``pip install 'spotlights[distributed]'``): nothing here
imports it at module import; :func:`import_ray` does, and turns its absence into one
line saying how to install it. :func:`ray_session` joins a running cluster
(``address="auto"`` or ``"HOST:PORT"``) or starts a local instance with ``workers`` CPUs,
and shuts down only what it started. Token authentication stays as Ray configures it
(on by default for local instances since Ray 2.59; see docs/scale-out.md for clusters).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

from .errors import SpotlightsError

BACKENDS = ("local", "ray")
INSTALL_HINT = "pip install 'spotlights[distributed]' (or: pip install 'ray>=2.52')"
# A task that raises something other than a SpotlightsError (a crashed worker, a lost node, an
# out-of-memory kill) is retried this many times before the run stops.
DEFAULT_RETRIES = 2


def import_ray():
    """The ``ray`` module; raises SpotlightsError (one line: how to install it) when it is missing."""
    try:
        import ray
    except ImportError:
        raise SpotlightsError(f"--backend ray needs Ray, which is not installed: {INSTALL_HINT}") from None
    return ray


def check_backend(backend: str) -> str:
    """Validate a ``--backend`` value (``local`` or ``ray``)."""
    b = str(backend or "local").lower()
    if b not in BACKENDS:
        raise SpotlightsError(f"unknown backend {backend!r}; choose from {', '.join(BACKENDS)}")
    return b


@contextlib.contextmanager
def ray_session(address: str | None = None, workers: int | None = None) -> Iterator[object]:
    """Yield the ``ray`` module with a connection: the one already initialised in this process,
    a running cluster (``address``: ``"auto"``, ``"HOST:PORT"`` or ``"ray://HOST:PORT"``), or a
    local instance with ``workers`` CPUs (default: all cores). What this call started, it stops.

    The local instance gets no dashboard and a small object store (meshes and depth arrays are
    small: a car is ~0.2 MB); its worker processes inherit this process's environment (so they
    import the same ``spotlights``). ``RAY_worker_niceness=N`` in the environment runs the
    workers at that niceness (a shared machine), the scheduler at the driver's. A local instance
    listens on the loopback interface only (set ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=1`` for Ray's
    default, every interface). A cluster address where nothing answers within
    :data:`CONNECT_TIMEOUT_S` is a one-line error. A SIGTERM handler of the caller's (the CLI's) is kept.
    """
    import signal
    import threading

    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    kw = dict(include_dashboard=False, log_to_driver=False, logging_level="ERROR", configure_logging=True)
    main_thread = threading.current_thread() is threading.main_thread()
    restore = None
    on_sigterm = signal.getsignal(signal.SIGTERM) if main_thread else None
    if not callable(on_sigterm):  # no handler of the caller's (a library call): Ray's own stays
        on_sigterm = None
    try:
        if address:
            _check_reachable(ray, address)
            # an address that accepts connections but is no Ray head: one try of 10 s (Ray: ~10 min, SIGTERM ignored)
            with _env_defaults(RAY_py_gcs_connect_timeout_s="10", RAY_gcs_server_port_wait_time_s="1"):
                ray.init(address=address, **kw)
        else:
            restore = _local_on_loopback(ray)
            n = max(1, int(workers or os.cpu_count() or 1))
            ray.init(num_cpus=n, object_store_memory=_local_store_bytes(), **kw)
    except SpotlightsError:
        raise
    except Exception as exc:  # ray.init raises bare Exceptions (e.g. a node that timed out during startup)
        where = f"connect to the Ray cluster at {address}" if address else "start a local Ray instance"
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        hint = ""
        if address and os.environ.get("RAY_AUTH_MODE", "") != "token":
            hint = (
                "; if the cluster uses token authentication (Ray's default for instances started by ray.init), "
                "set RAY_AUTH_MODE=token and give its token (RAY_AUTH_TOKEN or ~/.ray/auth_token), see "
                "docs/scale-out.md"
            )
        raise SpotlightsError(f"cannot {where}: {reason}{hint}") from None
    finally:
        if on_sigterm is not None:  # ray.init takes SIGTERM over (exit code 15 or 1, a stack dump): give it back
            signal.signal(signal.SIGTERM, on_sigterm)
        if restore is not None and not ray.is_initialized():
            restore()
    try:
        yield ray
    finally:
        ray.shutdown()
        if restore is not None:
            restore()


# Seconds to wait for a TCP connection to a cluster's address before giving up (Ray itself retries for ever).
CONNECT_TIMEOUT_S = 10.0
# Ray's switch that, off, makes a node advertise (and bind) the loopback address instead of the host's.
_RAY_CLUSTER_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def _check_reachable(ray, address: str) -> None:
    """Fail in seconds, with one line, when nothing accepts connections at a cluster's address
    (``ray.init`` would retry for ever and ignore SIGTERM). ``ray://`` (Ray Client) addresses are
    left to Ray."""
    import socket

    if str(address).startswith("ray://"):
        return
    try:  # the HOST:PORT Ray will dial ("auto": the running cluster; localhost: this node's address)
        target = ray._private.services.canonicalize_bootstrap_address(address)
    except Exception:  # private API or a bad address: check the address as given
        target = None if address == "auto" else address
    if not target:
        return  # "auto" without a cluster: Ray says so itself
    host, _, port = str(target).rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S):
            pass
    except (OSError, ValueError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc) or type(exc).__name__
        raise SpotlightsError(
            f"cannot connect to the Ray cluster at {address}: nothing answers at {target} within "
            f"{CONNECT_TIMEOUT_S:.0f} s ({reason}); is its head node running ('ray start --head')?"
        ) from None


@contextlib.contextmanager
def _env_defaults(**values: str) -> Iterator[None]:
    """Set the environment variables ``values`` that the user has not set, for the body only."""
    added = [k for k in values if k not in os.environ]
    os.environ.update({k: values[k] for k in added})
    try:
        yield
    finally:
        for k in added:
            os.environ.pop(k, None)


def _local_on_loopback(ray):
    """A local instance listens on the loopback interface only (Ray's default is every interface
    with the host's address), unless the environment sets ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER``.
    Returns the function that undoes it (after ``ray.shutdown``), or None."""
    if _RAY_CLUSTER_ENV in os.environ:
        return None  # the user chose
    constants = getattr(getattr(ray, "_private", None), "ray_constants", None)
    before = getattr(constants, "ENABLE_RAY_CLUSTER", None)
    os.environ[_RAY_CLUSTER_ENV] = "0"  # Ray's own processes read it at start
    if before is not None:
        constants.ENABLE_RAY_CLUSTER = False  # this process imported Ray already

    def restore() -> None:
        os.environ.pop(_RAY_CLUSTER_ENV, None)
        if before is not None:
            constants.ENABLE_RAY_CLUSTER = before

    return restore


def _local_store_bytes() -> int:
    """Object store of a local instance: 10% of memory, between 256 MiB and 2 GiB (what a build
    keeps there at once is one mesh per model plus the in-flight units' arguments)."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        total = 8 << 30
    return int(min(2 << 30, max(256 << 20, total // 10)))


def cluster_cpus(ray) -> int:
    """CPUs of the connected cluster (at least 1)."""
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def error_reason(exc: BaseException) -> str:
    """One line saying why a Ray task failed (the task's own exception when there is one)."""
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException):
        exc = cause
    text = str(exc).strip().splitlines()
    first = next((line for line in text if line.strip() and not line.startswith("Traceback")), "")
    return f"{type(exc).__name__}: {first[:200]}" if first else type(exc).__name__
