"""Stopping a long command cleanly on SIGINT (Ctrl-C) and SIGTERM (e.g. a cluster job's time limit).

A command that works through many items (pairs, frames) and writes each item's files runs its loop inside
:func:`interruptible`. The first signal only records itself (:attr:`Stop.requested`): the loop finishes
the item in flight, starts no other, stops its workers, writes what it has (its summaries) and exits with
:attr:`Stop.exit_code` (130 for SIGINT, 143 for SIGTERM: 128 + the signal's number). A second signal stops
at once: it raises :class:`Interrupted` (a ``KeyboardInterrupt``) in the main thread, except inside a
:func:`protected` block, which it lets finish first, so that a set of files written together is either
all there or not written::

    from stereogeo_cli.jobs.interrupt import Interrupted, interruptible, protected

    with interruptible(notice="stopping after the item in flight; {name} again to stop at once") as stop:
        try:
            for item in items:
                if stop.requested:  # the first signal: stop between items
                    break
                result = compute(item)  # a second signal raises Interrupted here...
                with protected():  # ...but only once these writes are done
                    write_files(result)
        except Interrupted:  # the second signal: stop now, keep what is written
            pass
        write_summary()
    if stop.requested:
        print(f"interrupted by {stop.name}: ...; run again with --resume", file=sys.stderr)
        sys.exit(stop.exit_code)

Handlers can only be installed by the main thread: elsewhere :func:`interruptible` installs none and its
:class:`Stop` is never requested (signals then act as they did). Inside an active :func:`interruptible`,
another :func:`interruptible` yields the same :class:`Stop`.

Worker processes: a terminal sends Ctrl-C to every process of its process group, and a cluster's SIGTERM
usually reaches every process of the job, so the workers would stop half-way (and print tracebacks). Let
the parent decide instead: start the workers inside :func:`signals_blocked` (the signals stay blocked in a
child until it ignores them) and call :func:`worker_ignores_signals` first in each worker (e.g. in a
``ProcessPoolExecutor``'s ``initializer``). After the first signal the parent lets the workers finish the
items in flight; after a second it kills them (``multiprocessing.Process.kill``) and removes what they
left unfinished (:func:`stereogeo_cli.io.atomic.write_files_atomically` leaves only ``.<name>.*.tmp``
files: a target file is never half written). A parent killed outright (SIGKILL, the OOM killer) can do
none of this: :func:`worker_exits_with_parent`, also called first in each worker, ends the worker as soon
as its parent is gone, so that no worker goes on alone (what it was writing is left as ``.tmp`` files,
which ``--resume`` removes).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from stereogeo_cli.errors import EXIT_INTERRUPTED, EXIT_TERMINATED

SIGNALS = (signal.SIGINT, signal.SIGTERM)  # what interruptible() handles by default


class Interrupted(KeyboardInterrupt):
    """Raised in the main thread by a second signal: stop at once. ``signum`` is that signal's number."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class Stop:
    """What the signals of an :func:`interruptible` block asked for.

    ``signum``: the first signal's number (None: none came); ``count``: the signals received.
    """

    def __init__(self, notice: str | None = None):
        self.signum: int | None = None
        self.count = 0
        self._notice = notice
        self._depth = 0  # protected() blocks the main thread is in
        self._pending: int | None = None  # a second signal that came inside protected()

    @property
    def requested(self) -> bool:
        """True once a signal has come: finish the work in flight, start no other."""
        return self.signum is not None

    @property
    def name(self) -> str | None:
        """The first signal's name ("SIGINT", "SIGTERM"), or None."""
        return None if self.signum is None else signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int | None:
        """The exit code for the first signal: 130 for SIGINT, 143 for SIGTERM (128 + its number)."""
        if self.signum is None:
            return None
        return {signal.SIGINT: EXIT_INTERRUPTED, signal.SIGTERM: EXIT_TERMINATED}.get(
            self.signum, 128 + int(self.signum)
        )

    def request(self, signum: int = signal.SIGINT) -> None:
        """Ask to stop as the signal ``signum`` does (the first time: record it; again: stop at once)."""
        self._handle(signum, None)

    def _handle(self, signum: int, frame) -> None:
        self.count += 1
        if self.signum is None:
            self.signum = signum
            if self._notice:
                try:  # a raw write: a handler may run while the main thread is inside print()
                    os.write(2, (self._notice.format(name=self.name) + "\n").encode())
                except OSError:
                    pass
            return
        if self._depth > 0:
            self._pending = signum
            return
        raise Interrupted(signum)


_active: Stop | None = None


def active() -> Stop | None:
    """The :class:`Stop` of the :func:`interruptible` block the process is in, or None."""
    return _active


@contextmanager
def interruptible(signals: Sequence[int] = SIGNALS, notice: str | None = None) -> Iterator[Stop]:
    """Handle ``signals`` (SIGINT and SIGTERM) in the block, and restore the previous handlers after it.

    Yields a :class:`Stop`: the first signal sets its ``signum``; a later one raises :class:`Interrupted`
    (outside :func:`protected` blocks). ``notice``: a line written to stderr when the first signal comes;
    ``{name}`` in it becomes the signal's name.
    """
    global _active
    if _active is not None:
        yield _active
        return
    stop = Stop(notice)
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {s: signal.getsignal(s) for s in signals}
    for s in signals:
        signal.signal(s, stop._handle)
    _active = stop
    try:
        yield stop
    finally:
        _active = None
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)


@contextmanager
def protected() -> Iterator[None]:
    """A block that a second signal does not cut: its :class:`Interrupted` is raised when the block ends.

    For short work that must be whole (writing one item's files). Only the main thread's blocks are
    protected (signal handlers run there); elsewhere, and outside :func:`interruptible`, it does nothing.
    """
    stop = _active
    if stop is None or threading.current_thread() is not threading.main_thread():
        yield
        return
    stop._depth += 1
    try:
        yield
    finally:
        stop._depth -= 1
        if stop._depth == 0 and stop._pending is not None:
            signum, stop._pending = stop._pending, None
            raise Interrupted(signum)


@contextmanager
def signals_blocked(signals: Sequence[int] = SIGNALS) -> Iterator[None]:
    """Block ``signals`` in the calling thread for the block; a signal that comes meanwhile is handled after.

    Start worker processes inside it (``ProcessPoolExecutor.submit`` starts them): a child keeps the
    signals blocked until :func:`worker_ignores_signals`, so that a Ctrl-C while it starts up neither
    stops it nor prints a traceback. No effect where the platform cannot block signals (Windows).
    """
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def worker_ignores_signals(signals: Sequence[int] = SIGNALS) -> None:
    """In a worker process: ignore ``signals`` (SIGINT and SIGTERM), and unblock them (see
    :func:`signals_blocked`): the parent finishes or stops the worker's work."""
    for s in signals:
        signal.signal(s, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, signals)


EXIT_PARENT_GONE = 1  # a worker's exit code when its parent is gone


def worker_exits_with_parent(poll_s: float = 1.0) -> None:
    """In a worker process: end the process (``os._exit``) as soon as its parent process is gone.

    A daemon thread waits on the parent's sentinel (:func:`multiprocessing.parent_process`: ready when the
    parent dies); a process that has none (not started by :mod:`multiprocessing`) instead checks every
    ``poll_s`` seconds whether it was handed to another parent (``os.getppid()``). No cleanup runs: a worker
    ignores SIGINT and SIGTERM (:func:`worker_ignores_signals`), and nothing else would stop it."""
    parent = multiprocessing.parent_process()
    sentinel = getattr(parent, "sentinel", None)
    ppid = os.getppid()

    def watch() -> None:
        if sentinel is not None:
            from multiprocessing.connection import wait

            try:
                wait([sentinel])  # blocks until the parent's end of the pipe is closed: it is gone
                os._exit(EXIT_PARENT_GONE)
            except OSError:  # the sentinel cannot be waited on: watch the parent's pid instead
                pass
        while os.getppid() == ppid:
            time.sleep(poll_s)
        os._exit(EXIT_PARENT_GONE)

    threading.Thread(target=watch, name="stereogeo-parent-watch", daemon=True).start()
