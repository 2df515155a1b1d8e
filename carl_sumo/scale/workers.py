"""Worker processes for SUMO jobs: one libsumo and one torch thread each, and what happens when
one dies.

libsumo runs one simulation per process, so ``simulate``, ``evaluate`` and ``study`` spread their
tasks over spawned processes. :func:`run_parallel` runs a function on every item in such a pool
(``concurrent.futures``, whose pool notices a worker that dies, where ``multiprocessing.Pool``
waits for its result forever). If a worker dies (killed, out of memory, a crash inside SUMO), the
tasks that had not finished run again in a fresh pool, and those lost again one at a time; every
task is deterministic given its arguments, so the results are the same as without the fault. A
task whose worker dies when it runs alone stops the job with :class:`WorkerError`, one line
naming it.

:func:`set_backend` replaces the pool by another runner of the same tasks: ``--ray`` sets
:func:`carl_sumo.scale.cluster.run_ray` (Ray remote tasks, the same results).
"""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterator, Sequence

from carl_sumo.interrupts import die_with_parent, run_task


class WorkerError(RuntimeError):
    """A worker process died again while running the same task."""


_backend: Callable[..., Iterator[Any]] | None = None


def set_backend(runner: Callable[..., Iterator[Any]] | None) -> None:
    """Run :func:`run_parallel`'s tasks with ``runner(fn, items, workers, describe, ordered)``
    instead of the local pool (None: the local pool again)."""
    global _backend
    _backend = runner


def worker_init() -> None:
    """Each worker (and a command that runs its tasks itself): one torch thread (the networks are
    small; threads only contend)."""
    import torch

    torch.set_num_threads(1)


def pool_worker_init() -> None:
    """A pool's worker process: :func:`worker_init`, and it dies with the command that started
    it, leaving Ctrl-C to it (:func:`carl_sumo.interrupts.die_with_parent`)."""
    die_with_parent()
    worker_init()


def stop_children(timeout_s: float = 5.0) -> None:
    """Terminate every worker process this process started that still runs (after an
    interrupt), and wait up to ``timeout_s`` for them; those still alive then are killed."""
    children = mp.active_children()
    for child in children:
        child.terminate()
    for child in children:
        child.join(timeout_s)
        if child.is_alive():
            child.kill()
            child.join(1.0)


def _pool(workers: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"),
                               initializer=pool_worker_init)


def _run_pool(fn: Callable[..., Any], items: Sequence[tuple], indices: Sequence[int],
              workers: int, lost: list[int]) -> Iterator[tuple[int, Any]]:
    """(index, result) of ``fn(*items[i])`` for ``indices`` in one fresh pool, as they finish;
    the indices of tasks lost with a dead worker are appended to ``lost``."""
    executor = _pool(workers)
    futures = {executor.submit(run_task, fn, *items[i]): i for i in indices}
    finished_all = False
    try:
        while futures:
            finished, _ = wait(futures, timeout=WATCHDOG_S, return_when=FIRST_COMPLETED)
            if not finished and _has_dead_worker(executor):
                # a worker died and the pool has not said so (seen when one is killed while it
                # starts, on a loaded machine): its tasks count as lost, as with a broken pool
                lost.extend(futures.values())
                futures.clear()
            for future in finished:
                i = futures.pop(future)
                try:
                    result = future.result()
                except BrokenProcessPool:
                    lost.append(i)
                    continue
                yield i, result
        finished_all = True
    finally:
        processes = list((getattr(executor, "_processes", None) or {}).values())
        call_queue = getattr(executor, "_call_queue", None)  # shutdown forgets it
        abandoned = lost or not finished_all  # an exception, an interrupt, a closed generator
        executor.shutdown(wait=not abandoned, cancel_futures=True)
        if abandoned:  # a broken or abandoned pool: no worker of it may outlive it
            for process in processes:
                if process.is_alive():
                    process.terminate()
            _unblock_feeder(call_queue)


def _unblock_feeder(call_queue) -> None:
    """Let a broken pool's queue feeder thread finish. When a worker dies while that thread is
    writing a task into the pipe to the workers, the write blocks for ever (this process holds the
    pipe's read end too), and the pool's manager thread, which joins the feeder, blocks the
    interpreter's exit (CPython 3.11; seen with ``simulate``'s large event chunks). Closing this
    process's read end makes the write fail, and the feeder hands that error to the lost task."""
    feeder = getattr(call_queue, "_thread", None)
    if feeder is not None:
        feeder.join(timeout=1.0)
        if not feeder.is_alive():  # it finished by itself: nothing to unblock
            return
    reader = getattr(call_queue, "_reader", None)
    if reader is not None:
        try:
            reader.close()
        except OSError:
            pass


WATCHDOG_S = 10.0
"""How often (s) a pool with nothing finished checks its worker processes itself."""


def _has_dead_worker(executor: ProcessPoolExecutor) -> bool:
    """Whether a worker process of the pool has exited (an idle worker never does)."""
    processes = getattr(executor, "_processes", None) or {}
    return any(p.exitcode is not None for p in list(processes.values()))


def run_parallel(fn: Callable[..., Any], items: Sequence[tuple], workers: int,
                 describe: Callable[[tuple], str] = repr, ordered: bool = True
                 ) -> Iterator[Any]:
    """``fn(*item)`` for every item in ``workers`` spawned processes: results in the order of
    ``items`` (``ordered``) or as they finish. The tasks lost with a dead worker run again in a
    fresh pool; those lost a second time run one at a time, each in a fresh worker, and a task
    whose worker dies then raises :class:`WorkerError` naming it (``describe``). Exceptions
    raised by ``fn`` itself propagate. With a backend set (:func:`set_backend`) it runs them."""
    if _backend is not None:
        yield from _backend(fn, items, workers, describe, ordered)
        return
    done: dict[int, Any] = {}
    next_out = 0
    todo: list[int] = list(range(len(items)))
    for round_workers in (workers, workers, 1):
        lost: list[int] = []
        if round_workers == 1 and todo:  # the third round: alone, so a killer task is named
            for i in sorted(todo):
                again: list[int] = []
                for j, result in _run_pool(fn, items, [i], 1, again):
                    done[j] = result
                if again:
                    raise WorkerError(f"a worker process died three times while running "
                                      f"{describe(items[i])}; run it again, or with --workers 1 "
                                      "to see its error")
                if not ordered:
                    yield done.pop(i)
                while ordered and next_out in done:
                    yield done.pop(next_out)
                    next_out += 1
            todo = []
            break
        for i, result in _run_pool(fn, items, sorted(todo), round_workers, lost):
            if ordered:
                done[i] = result
            else:
                yield result
            while ordered and next_out in done:
                yield done.pop(next_out)
                next_out += 1
        todo = lost
        if not todo:
            break
    while ordered and next_out in done:
        yield done.pop(next_out)
        next_out += 1
