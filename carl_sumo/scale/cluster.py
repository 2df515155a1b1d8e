"""Ray as the task backend: ``--ray ADDRESS`` runs the SUMO tasks of ``simulate``, ``evaluate``,
``study`` (and ``train``'s rollout workers, :class:`carl_sumo.learn.vec_env.RayVecPlatoon`) as Ray
remote tasks instead of the local spawned-process pool of :mod:`carl_sumo.scale.workers`.

- ``local`` starts a Ray runtime inside this process (``--workers`` CPUs, no dashboard);
- ``auto`` joins the cluster started on this machine with ``ray start --head``;
- ``HOST:PORT`` joins the cluster whose head listens there (``ray start --address HOST:PORT`` on
  the other machines).

Each task runs the same function with the same arguments in a Ray worker process, with its own
libsumo (one simulation at a time per process) and one torch thread, so the results are those of
the local pool. A task whose worker process dies runs again (twice at most, Ray's retries); a
third death raises :class:`carl_sumo.scale.workers.WorkerError` naming it. Ray is optional: it is
imported only here, when ``--ray`` is given (``pip install -e ".[ray]"``).
"""

from __future__ import annotations

import logging
import os
import re
import socket
from collections import Counter
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Sequence

from carl_sumo.scale import workers
from carl_sumo.errors import InputError
from carl_sumo.interrupts import held

EXTRA_HINT = ("--ray needs the optional Ray extra: pip install -e \".[ray]\" (or leave out --ray "
              "to use local processes)")
"""The one line a command prints when ``--ray`` is given but Ray is not installed."""

TASK_RETRIES = 2
"""Times Ray runs a task again whose worker process died (as the local pool's two retries)."""

CONNECT_TIMEOUT_S = 3.0
"""How long (s) the head's port may take to accept a connection before the address is bad."""

last_nodes: Counter = Counter()
"""Tasks per Ray node id since :func:`connect` (what ran where)."""


def import_ray():
    """The ``ray`` module, or InputError (one line: how to install it) when it is missing.

    Ray's C++ failure-signal handler is left out (unless the environment asks for it): it would
    take SIGTERM from this process's own handler and can abort the process instead of letting
    the command clean up and exit with 143."""
    os.environ.setdefault("RAY_DISABLE_FAILURE_SIGNAL_HANDLER", "1")
    try:
        import ray
    except ImportError:
        raise InputError(EXTRA_HINT) from None
    return ray


def check_address(address: str) -> str:
    """``address`` if it is ``local``, ``auto`` or ``HOST:PORT``, else InputError."""
    if address in ("local", "auto"):
        return address
    match = re.fullmatch(r"([A-Za-z0-9.\-]+|\[[0-9A-Fa-f:]+\]):(\d{1,5})", address)
    if not match or not 0 < int(match.group(2)) < 65536:
        raise InputError(f"--ray {address!r} is not an address: give local (a Ray runtime in "
                         "this process), auto (the cluster started here with `ray start --head`)"
                         " or HOST:PORT of a cluster's head")
    return address


def _probe(address: str) -> None:
    """InputError unless something accepts TCP connections at HOST:PORT (Ray's own connect
    retries for a minute before it gives up)."""
    host, port = address.rsplit(":", 1)
    try:
        with socket.create_connection((host.strip("[]"), int(port)), CONNECT_TIMEOUT_S):
            pass
    except OSError as exc:
        raise InputError(f"--ray {address}: no Ray cluster answers there "
                         f"({exc.strerror or type(exc).__name__}); start one with `ray start "
                         f"--head --port {port}` on that machine, or give --ray local") from None


@contextmanager
def _keeping_sigterm(ray: Any, keep: bool) -> Iterator[None]:
    """While the block runs, and where ``keep``, ``ray.init`` leaves SIGTERM's handler as it is
    (it would make SIGTERM a bare ``sys.exit(15)`` in the middle of its start-up)."""
    utils = ray._private.utils
    original = utils.set_sigterm_handler
    if keep:
        utils.set_sigterm_handler = lambda handler: None
    try:
        yield
    finally:
        utils.set_sigterm_handler = original


def connect(address: str, num_cpus: int | None = None) -> None:
    """Start (``local``, with ``num_cpus`` CPUs) or join (``auto``, ``HOST:PORT``) a Ray runtime
    and make it the backend of :func:`carl_sumo.scale.workers.run_parallel`; InputError (one line) for
    a missing extra, a bad address or no cluster there."""
    check_address(address)
    ray = import_ray()
    if address not in ("local", "auto"):
        _probe(address)
    options: dict[str, Any] = {"logging_level": logging.ERROR, "configure_logging": True}
    try:
        with held() as holding, _keeping_sigterm(ray, holding):
            if address == "local":
                ray.init(num_cpus=num_cpus, include_dashboard=False, **options)
            else:
                ray.init(address=address, **options)
    except ConnectionError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"--ray {address}: cannot join a Ray cluster ({first}); start one with "
                         "`ray start --head`, or give --ray local (a cluster with token "
                         "authentication, Ray's default for `ray start`, needs RAY_AUTH_MODE=token "
                         "and its token: docs/scale.md)") from None
    except BaseException:  # a stop signal held while Ray started: Ray's processes stop too
        ray.shutdown()
        raise
    last_nodes.clear()
    workers.set_backend(run_ray)


def disconnect() -> None:
    """Leave the Ray runtime (a ``local`` one stops with its worker processes)."""
    workers.set_backend(None)
    ray = import_ray()
    if ray.is_initialized():
        ray.shutdown()


def cluster_cpus() -> int:
    """CPUs of the Ray runtime this process is connected to."""
    return int(import_ray().cluster_resources().get("CPU", 0))


def require_cpus(n: int, option: str) -> None:
    """InputError when the Ray runtime has fewer than ``n`` CPUs for ``option``'s actors."""
    cpus = cluster_cpus()
    if cpus < n:
        raise InputError(f"{option} {n} needs {n} CPUs on the Ray cluster, which has {cpus}; "
                         f"give {option} {max(cpus, 1)} or add nodes")


_INITIALISED = False


def _call(fn: Callable[..., Any], args: tuple, cwd: str) -> tuple[str, Any]:
    """In a Ray worker: (node id, ``fn(*args)``), from the driver's working folder (relative
    paths such as ``networks/i80.net.xml`` mean the same there), with one torch thread."""
    global _INITIALISED
    import ray

    if not _INITIALISED:
        workers.worker_init()
        _INITIALISED = True
    if os.path.isdir(cwd) and os.getcwd() != cwd:
        os.chdir(cwd)
    return ray.get_runtime_context().get_node_id(), fn(*args)


def run_ray(fn: Callable[..., Any], items: Sequence[tuple], n_workers: int,
            describe: Callable[[tuple], str] = repr, ordered: bool = True) -> Iterator[Any]:
    """``fn(*item)`` for every item as Ray remote tasks (1 CPU each): results in the order of
    ``items`` (``ordered``) or as they finish. ``n_workers`` is not used: the cluster's CPUs
    decide how many run at once. Exceptions raised by ``fn`` propagate as themselves."""
    ray = import_ray()
    remote = ray.remote(num_cpus=1, max_retries=TASK_RETRIES, retry_exceptions=False)(_call)
    cwd = os.getcwd()
    fn_ref = ray.put(fn)
    pending = {remote.remote(fn_ref, tuple(item), cwd): i for i, item in enumerate(items)}
    done: dict[int, Any] = {}
    next_out = 0
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            i = pending.pop(ready[0])
            node, result = _result(ray, ready[0], items[i], describe)
            last_nodes[node] += 1
            if not ordered:
                yield result
                continue
            done[i] = result
            while next_out in done:
                yield done.pop(next_out)
                next_out += 1
    finally:
        for ref in pending:  # an error or an abandoned generator: nothing keeps running
            ray.cancel(ref, force=True)


def _result(ray, ref, item: tuple, describe: Callable[[tuple], str]) -> tuple[str, Any]:
    """The (node, result) of a finished task; its own exception, or WorkerError when its worker
    process died more than :data:`TASK_RETRIES` times."""
    from ray.exceptions import RayTaskError, WorkerCrashedError

    try:
        return ray.get(ref)
    except RayTaskError as exc:
        cause = getattr(exc, "cause", None)
        if isinstance(cause, BaseException):
            raise cause from None
        raise
    except WorkerCrashedError:
        raise workers.WorkerError(f"a Ray worker process died {TASK_RETRIES + 1} times while "
                                  f"running {describe(item)}; run it again, or without --ray "
                                  "and with --workers 1 to see its error") from None


def describe_nodes() -> str:
    """``N tasks on K Ray node(s): ID…=n, ...`` since :func:`connect`."""
    parts = ", ".join(f"{node[:8]}={n}" for node, n in sorted(last_nodes.items()))
    return (f"{sum(last_nodes.values())} tasks on {len(last_nodes)} Ray node(s): {parts}"
            if last_nodes else "no Ray tasks")
