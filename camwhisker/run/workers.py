"""Local worker processes that stop when told and never outlive their parent.

:func:`run_in_processes` runs calls on a process pool and yields their results
as they finish. Interrupted (KeyboardInterrupt, or the generator closed early),
it stops within :data:`STOP_GRACE_S`: calls not started are dropped, running
ones get SIGTERM and unwind (so the temporary files of
:func:`camwhisker.files.atomic.atomic_path` are removed), and a worker still alive
after the grace time is killed.

A worker ignores SIGINT: a terminal's Ctrl-C reaches the whole process group,
and the parent alone decides what stops. On Linux each worker asks the kernel
for SIGTERM when its parent dies (``prctl(PR_SET_PDEATHSIG)``), chosen because
the kernel sends it at the moment of death, kill -9 included, even to a worker
blocked waiting for work, with no thread polling and no pipe to keep out of
the sibling workers. Elsewhere workers stop only when a live parent tells them.

:func:`stop_signals_interrupt` turns SIGINT and SIGTERM into KeyboardInterrupt
in the parent, so both take the same path.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed

__all__ = ["STOP_GRACE_S", "REDELIVER_S", "Stopped", "run_in_processes",
           "stop_signals_interrupt"]

#: How long running calls get to unwind after SIGTERM before they are killed.
STOP_GRACE_S = 2.0
#: A stop signal that landed in a finaliser is sent again this much later.
REDELIVER_S = 0.05

_PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>
# PR_SET_PDEATHSIG watches the process that forked the worker: fork it from this one.
_CONTEXT = "fork" if sys.platform == "linux" else None


class Stopped(SystemExit):
    """Raised in a worker's running call by SIGTERM: unwinds it, then the worker exits.

    A SystemExit, so a call's ``except Exception`` does not swallow it."""


# The worker's state, for its SIGTERM handler.
_in_call = False
_stopping = False


def run_in_processes(fn: Callable, calls: Iterable[tuple], workers: int) -> Iterator[object]:
    """``fn(*args)`` for each ``args`` in ``calls`` on ``workers`` processes; yields the
    results in the order they finish. Closing the generator (or an exception while it
    waits, such as KeyboardInterrupt) stops the workers as the module docstring says."""
    before = set(multiprocessing.active_children())
    context = multiprocessing.get_context(_CONTEXT)
    pool = ProcessPoolExecutor(workers, context, initializer=_init_worker, initargs=(os.getpid(),))
    finished = False
    try:
        futures = [pool.submit(_call, fn, *args) for args in calls]
        for fut in as_completed(futures):
            yield fut.result()
        finished = True
    finally:
        if finished:
            pool.shutdown()
        else:
            _stop(pool, before)


def _stop(pool: ProcessPoolExecutor, before: set) -> None:
    """Drop the calls not started, SIGTERM the workers, kill those left after the grace time."""
    pool.shutdown(wait=False, cancel_futures=True)
    workers = [p for p in multiprocessing.active_children() if p not in before]
    for p in workers:
        p.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    for p in workers:
        p.join(max(0.0, deadline - time.monotonic()))
    for p in workers:
        if p.is_alive():
            p.kill()
            p.join()


def _call(fn: Callable, *args):
    global _in_call
    try:
        _in_call = True  # inside the try: a stop from here on unwinds into the except below
        result = fn(*args)
    except Stopped:
        os._exit(1)  # the call has unwound (its temporary files are gone): take no other
    finally:
        _in_call = False
    if _stopping:  # the call caught the stop and went on: its outputs are whole, leave now
        os._exit(1)
    return result


def _init_worker(parent_pid: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _on_sigterm)
    if sys.platform == "linux":
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent_pid:  # the parent died before the request took effect
            os._exit(1)


def _on_sigterm(_signum, _frame) -> None:
    """Unwind the running call; between calls there is nothing to unwind, so exit at
    once (an exception there would be caught by the pool and sent back as a result)."""
    global _stopping
    if _stopping:  # a second SIGTERM must not cut the unwinding short
        return
    _stopping = True
    if not _in_call:
        os._exit(1)
    raise Stopped()


def _in_finaliser(frame) -> bool:
    """Whether ``frame`` or a frame that called it is a ``__del__``."""
    while frame is not None:
        if frame.f_code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


@contextlib.contextmanager
def stop_signals_interrupt() -> Iterator[None]:
    """In the main thread: the first SIGINT or SIGTERM raises KeyboardInterrupt, later
    ones are ignored (the stop under way is bounded). A SIGINT ignored on entry (a job
    started in the background) stays ignored. Elsewhere: nothing changes.

    A signal that arrives while a finaliser (``__del__``, or what it calls) runs is
    sent again :data:`REDELIVER_S` later: Python ignores an exception raised in a
    finaliser, and the stop would be lost (numba's compiler frees its LLVM objects in
    finalisers, so a batch stopped in its first seconds would run on)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    raised = False

    def interrupt(signum, frame):
        nonlocal raised
        if raised:
            return
        if _in_finaliser(frame):
            threading.Timer(REDELIVER_S, os.kill, (os.getpid(), signum)).start()
            return
        raised = True
        raise KeyboardInterrupt

    sigs = [signal.SIGTERM]
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        sigs.append(signal.SIGINT)
    old = {sig: signal.signal(sig, interrupt) for sig in sigs}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
