"""Where build tasks run: a local process pool, threads or the calling process, or a Dask cluster.

Decision 5 of the design: a build is a graph of independent tile tasks submitted to a
``concurrent.futures.Executor``. This module makes that executor and runs a batch of tasks through it
with a progress bar; it knows nothing about tiles. Task functions must be importable module-level
functions with picklable arguments, because they run in spawned processes or on Dask workers.

It must not import VTK or Qt, and it imports ``distributed`` only when a scheduler address is given.
"""

from __future__ import annotations

import atexit
import ctypes
import functools
import multiprocessing
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, Generic, TypeVar

T = TypeVar("T")


class Completions(Generic[T]):
    """Submitted futures handed back in the order they finish.

    Each future's done-callback queues it, so taking the next one costs the same however many are
    pending. ``concurrent.futures.wait(pending, FIRST_COMPLETED)`` installs and removes a waiter on
    every pending future at each call: O(n²) lock operations under the GIL for n tasks, which the build
    threads wait for.
    """

    def __init__(self) -> None:
        self._done: queue.SimpleQueue[Future[T]] = queue.SimpleQueue()
        self.pending: set[Future[T]] = set()

    def add(self, fut: Future[T]) -> None:
        self.pending.add(fut)
        fut.add_done_callback(self._done.put)

    def __len__(self) -> int:
        return len(self.pending)

    def next(self) -> Future[T]:
        """The next finished future (blocks until one is)."""
        fut = self._done.get()
        self.pending.discard(fut)
        return fut

    def cancel(self) -> None:
        """Cancel the futures not started yet."""
        for fut in self.pending:
            fut.cancel()


class InlineExecutor(Executor):
    """Runs each task at submit time in the calling process (``workers=0``).

    For small builds, where starting worker processes (each imports numpy and numba) costs more than
    the parallelism saves, and for debugging with a plain traceback.
    """

    def submit(self, fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> Future[T]:  # type: ignore[override]
        fut: Future[T] = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:
            fut.set_exception(exc)
        return fut


def _worker_init(parent_pid: int) -> None:
    """Runs first in every local worker process.

    A worker that has run numba-compiled kernels takes about 0.4 s to tear its interpreter down (LLVM and
    module finalisers), and the pool waits for that at shutdown, once per build. Workers hold no state
    that needs it: every task writes its files, or flushes its journal record, before it returns. So the
    last exit handler flushes the standard streams and ends the process at once.

    A worker also dies with the build that started it (:func:`_die_with_parent`): a build killed with
    SIGKILL runs no clean-up, and its workers would otherwise live on as orphans holding their memory.
    """
    atexit.register(_exit_now)
    _die_with_parent(parent_pid)


# prctl(2) option: the signal the kernel sends this process when the thread that created it exits.
_PR_SET_PDEATHSIG = 1
_PARENT_POLL_S = 1.0


def _die_with_parent(parent_pid: int) -> None:
    """End this process when ``parent_pid`` dies, however it dies.

    On Linux the kernel does it: ``prctl(PR_SET_PDEATHSIG, SIGKILL)``. The signal follows the *thread*
    that created the worker; the pool creates its workers from the thread that submits (the build's), which
    outlives them. A daemon thread that polls the parent pid every second is the fallback where prctl is
    missing (other systems) and covers a parent that died before prctl was set. Killing is safe: every task
    writes under temporary names and renames, so a killed task leaves nothing a rerun would trust.
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # the parent died before the line above took effect
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), name="citylod-parent-watch", daemon=True).start()


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(_PARENT_POLL_S)
    os._exit(1)


def _exit_now() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    os._exit(0)


@functools.cache
def _bar_class() -> Any:
    from tqdm.auto import tqdm

    class _Bar(tqdm):  # type: ignore[misc, valid-type]
        monitor_interval = 0

    return _Bar


class _NoBar:
    """What :func:`progress_bar` returns when it is disabled: the calls a bar takes, doing nothing (importing
    ``tqdm.auto`` costs a fresh process ≈ 45 ms, asyncio included, for a bar nobody sees)."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def progress_bar(**kwargs: Any) -> Any:
    """A tqdm bar (``tqdm.auto``) that starts no monitor thread: tqdm's monitor, a thread of its own,
    would make :func:`fork_is_safe` false for the next build of the process. With ``disable=True``, a bar
    that shows nothing and needs no tqdm."""
    if kwargs.get("disable"):
        return _NoBar()
    return _bar_class()(**kwargs)


def fork_is_safe() -> bool:
    """Whether worker processes may be forked from this one: Linux, and no other Python thread running
    (a thread holding a lock at the fork would leave it locked in the child)."""
    return (sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()
            and threading.active_count() == 1)


def _worker_count(workers: int | None) -> int:
    return (os.cpu_count() or 1) if workers is None else int(workers)


def describe(workers: int | None = None, scheduler: Any = None, *, threads: bool = False,
             fork: bool = False) -> str:
    """Where :func:`make_executor` with these arguments runs the tasks, in words ("2 forked processes")."""
    if scheduler is not None:
        return "a Dask cluster"
    n = _worker_count(workers)
    if n <= 0:
        return "inline"
    return f"{n} {'threads' if threads else 'forked processes' if fork else 'processes'}"


@contextmanager
def make_executor(workers: int | None = None, scheduler: Any = None, *, threads: bool = False,
                  fork: bool = False) -> Iterator[Executor]:
    """An executor for build tasks, shut down when the ``with`` block ends.

    Parameters
    ----------
    workers
        Local worker processes (threads with ``threads``); None = CPU count; 0 = run in the calling
        process. Ignored when ``scheduler`` is given.
    threads
        Threads of the calling process instead of worker processes: for tasks whose compiled kernels
        release the GIL, no start-up (a spawned worker imports numpy, numba, rasterio and loads the
        compiled kernels, ≈1 s) and no pickling of results.
    fork
        Worker processes forked from this one instead of spawned: no start-up (they inherit the imported
        modules and the loaded kernels) and no GIL shared between tasks. Only where
        :func:`fork_is_safe`; the caller checks, as the threads of the process are its business.
    scheduler
        A Dask scheduler address (``tcp://HOST:PORT``), or a ``distributed.Client``; the tasks then run
        on that cluster's workers, which need citylod importable and the build's files reachable at
        the same paths.

    Yields
    ------
    concurrent.futures.Executor
    """
    if scheduler is not None:
        import distributed

        own = not isinstance(scheduler, distributed.Client)
        client: distributed.Client = (distributed.Client(scheduler, set_as_default=False) if own
                                      else scheduler)
        try:
            yield client.get_executor()
        finally:
            if own:
                client.close()
        return
    n = _worker_count(workers)
    if n <= 0:
        yield InlineExecutor()
        return
    if threads:
        tpool = ThreadPoolExecutor(max_workers=n, thread_name_prefix="citylod-build")
        try:
            yield tpool
        finally:
            tpool.shutdown(wait=True, cancel_futures=True)
        return
    # spawn unless asked to fork: the parent may hold threads (Dask, tqdm monitor, OpenMP) that fork
    # would copy in a locked state, and spawn behaves the same on Linux, macOS and Windows.
    pool = ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("fork" if fork else "spawn"),
                               initializer=_worker_init, initargs=(os.getpid(),))
    try:
        yield pool
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def run_tasks(executor: Executor, fn: Callable[..., T], tasks: Iterable[Any], *, progress: bool = True,
              desc: str = "", max_in_flight: int | None = None) -> Iterator[T]:
    """Run ``fn(*task)`` for every task (a tuple of arguments) and yield the results as they complete.

    Results come in completion order, not submission order; return something that identifies the task
    when the caller needs to know which one finished. At most ``max_in_flight`` tasks are submitted at a
    time (default 4096), so a long task list does not sit in the scheduler's memory at once. The first
    task that raises cancels the tasks not yet started and re-raises in the caller.

    Parameters
    ----------
    executor
        From :func:`make_executor` (or any ``concurrent.futures.Executor``).
    fn
        A module-level function (it is pickled by reference).
    tasks
        Argument tuples; a non-tuple item is passed as the single argument.
    progress
        Show a tqdm progress bar on stderr.
    desc
        The progress bar's label.
    """
    items = [t if isinstance(t, tuple) else (t,) for t in tasks]
    limit = max_in_flight or 4096
    bar = progress_bar(total=len(items), desc=desc, disable=not progress, unit="task", leave=False)
    running: Completions[T] = Completions()
    it = iter(items)
    try:
        while True:
            while len(running) < limit:
                args = next(it, None)
                if args is None:
                    break
                running.add(executor.submit(fn, *args))
            if not running:
                break
            fut = running.next()
            bar.update(1)
            yield fut.result()
    finally:
        running.cancel()
        bar.close()
