"""Stopping on a signal: SIGTERM and SIGHUP stop a command as Ctrl-C (SIGINT) does.

The command line (:func:`carl_sumo.cli.main`) installs :func:`stop_on_signals` for the time a
command runs: SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (a KeyboardInterrupt) in the
main thread, so every ``finally`` runs: temporary output files are removed
(:mod:`carl_sumo.files`), worker pools, Ray runtimes and sumo-gui are stopped, and the command
exits with status 128 + the signal's number, writing nothing. A second signal while that clean-up
runs is ignored (SIGKILL still stops the process at once). A signal that arrives while C code
runs a Python callback (numba's compiler, through llvmlite and ctypes) raises in the callback,
where C drops the exception and Python reports it to ``sys.unraisablehook``: that hook here
delivers the signal again 0.05 s later, once the callback has returned, and prints nothing.

Worker processes call :func:`die_with_parent`: they leave Ctrl-C to their command (no traceback
of theirs on the terminal), and on Linux they are killed when the process that started them
ends, even by SIGKILL, so no worker outlives its command. When the command stops its workers
(SIGTERM), a task run through :func:`run_task` is interrupted as a command is, so its own
clean-up runs (a study run's temporary folder), and the worker then ends.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager
from typing import Any, Callable, Iterator

STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP")
                     if hasattr(signal, name))
"""The signals that stop a command cleanly (SIGHUP: the terminal went away)."""


class Interrupted(KeyboardInterrupt):
    """A stop signal arrived; ``signum`` is its number (exit status 128 + signum)."""

    def __init__(self, signum: int):
        super().__init__(f"signal {signum}")
        self.signum = signum

    @property
    def exit_status(self) -> int:
        return 128 + self.signum


def exit_status(exc: KeyboardInterrupt) -> int:
    """The exit status of a command stopped by ``exc``: 128 + the signal's number, also where a
    library turned the Interrupted into a plain KeyboardInterrupt (Ray's waits do); 130 for a
    KeyboardInterrupt without a signal seen."""
    if isinstance(exc, Interrupted):
        return exc.exit_status
    return 128 + (_received or signal.SIGINT)


_stopping = False
_received = 0  # the stop signal seen last (0: none)


def _raise(signum: int, frame: Any) -> None:
    """Raise Interrupted once; later signals arrive while the command cleans up: ignored."""
    global _stopping, _received
    if _stopping:
        return
    _stopping, _received = True, signum
    raise Interrupted(signum)


def ignore_stop_signals() -> None:
    """Ignore the stop signals from now on (main thread only): a command that a signal stopped
    is exiting with 128 + n, and a second signal (a repeated Ctrl-C, a SIGTERM soon after the
    first) must not kill it by the signal on its way out."""
    if threading.current_thread() is threading.main_thread():
        for s in STOP_SIGNALS:
            signal.signal(s, signal.SIG_IGN)


def stopped() -> bool:
    """Whether a stop signal has reached this command (since :func:`stop_on_signals`)."""
    return _received != 0


_previous_unraisable = sys.unraisablehook  # the hook :func:`_lost_in_callback` passes the rest to


def _lost_in_callback(unraisable: Any) -> None:
    """``sys.unraisablehook``: an :class:`Interrupted` raised inside a C callback is lost there;
    deliver its signal again from a timer thread (the handler then raises in Python code).
    Anything else goes to the hook that was there before."""
    global _stopping
    exc = unraisable.exc_value
    if not isinstance(exc, Interrupted):
        _previous_unraisable(unraisable)
        return
    _stopping = False
    timer = threading.Timer(0.05, os.kill, (os.getpid(), exc.signum))
    timer.daemon = True
    timer.start()


def _catch_lost_interrupts() -> None:
    """Install :func:`_lost_in_callback` as ``sys.unraisablehook`` (once)."""
    global _previous_unraisable
    if sys.unraisablehook is not _lost_in_callback:
        _previous_unraisable, sys.unraisablehook = sys.unraisablehook, _lost_in_callback


def stop_on_signals() -> Callable[[], None]:
    """Make SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (main thread only; elsewhere
    nothing changes); returns the function that puts the previous handlers back."""
    global _stopping, _received
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    _stopping, _received = False, 0
    previous = {s: signal.signal(s, _raise) for s in STOP_SIGNALS}
    _catch_lost_interrupts()

    def restore() -> None:
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
        if sys.unraisablehook is _lost_in_callback:
            sys.unraisablehook = _previous_unraisable

    return restore


@contextmanager
def held() -> Iterator[bool]:
    """Stop signals that arrive while the block runs wait until it has ended, then stop the
    command as usual (a library's start-up that a signal must not cut in half: ``ray.init``,
    whose half-started runtime crashes the process on its way out). Yields whether it holds
    them: only where :func:`stop_on_signals` is active, in the main thread."""
    if threading.current_thread() is not threading.main_thread() or not any(
            signal.getsignal(s) is _raise for s in STOP_SIGNALS):
        yield False
        return
    pending: list[int] = []
    for s in STOP_SIGNALS:
        signal.signal(s, lambda signum, frame: pending.append(signum))
    try:
        yield True
    finally:
        for s in STOP_SIGNALS:
            signal.signal(s, _raise)
    if pending:
        _raise(pending[0], None)


_in_task = False  # whether this worker process runs a task now


def _stop_worker(signum: int, frame: Any) -> None:
    """In a worker: a task stops as a command does (its ``finally`` blocks remove its temporary
    files, :func:`run_task` then ends the process); an idle worker ends at once."""
    if _in_task:
        _raise(signum, frame)
    os._exit(128 + signum)


def run_task(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a worker process; SIGTERM (its command stopping it) interrupts it, and
    once its clean-up has run the worker exits without a traceback or a result."""
    global _in_task
    _in_task = True
    try:
        return fn(*args)
    except Interrupted as exc:
        os._exit(exc.exit_status)
    finally:
        _in_task = False


def die_with_parent() -> None:
    """In a worker process: leave Ctrl-C and a hang-up (which a terminal sends to every process
    of the command) to the command, which stops its workers itself; and (Linux) be killed when
    the process that started it ends, however it ends: a worker whose parent has already gone
    exits at once."""
    for s in (getattr(signal, "SIGINT", None), getattr(signal, "SIGHUP", None)):
        if s is not None and threading.current_thread() is threading.main_thread():
            signal.signal(s, signal.SIG_IGN)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _stop_worker)  # a task cleans up (see run_task)
        _catch_lost_interrupts()
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import multiprocessing

    parent = multiprocessing.parent_process()
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if parent is not None and os.getppid() != parent.pid:  # it ended before prctl
        os._exit(1)
