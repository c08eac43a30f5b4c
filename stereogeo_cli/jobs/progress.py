"""Progress on stderr, for the long commands: the pairs of a batch (:class:`PairProgress`) and the stages
of a sequence (:class:`StageProgress`)."""

from __future__ import annotations

import sys
import time


class PairProgress:
    """Reports finished pairs on stderr: a Rich progress bar on a terminal, else one plain line per pair."""

    def __init__(self, rich: bool):
        self.rich = rich
        self.bar = None

    def __enter__(self) -> PairProgress:
        if self.rich:
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(
                TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                console=Console(stderr=True), transient=False,
            )  # fmt: skip
            self.bar.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.__exit__(*exc)

    def stage(self, description: str, total: int) -> None:
        self.done, self.total, self.description = 0, total, description
        if self.bar is not None:
            self.task = self.bar.add_task(description, total=total)

    def line(self, text: str) -> None:
        if self.bar is not None:
            self.bar.console.print(text, markup=False, highlight=False)
        else:
            print(text, file=sys.stderr, flush=True)

    def finished(self, outcome) -> None:
        """One pair is done: ``outcome`` has its ``name``, ``status``, ``error`` and ``time_ms``."""
        self.done += 1
        if outcome.status != "ok":
            self.line(f"{self.description}: {outcome.name}: failed: {outcome.error}")
        elif self.bar is None:
            done = f"{self.done}/{self.total}"
            self.line(f"{self.description}: {done} {outcome.name}: ok ({outcome.time_ms:.0f} ms)")
        if self.bar is not None:
            self.bar.advance(self.task)


class StageProgress:
    """A long command's stages on stderr, called as ``progress(done, total, stage)`` (a new ``stage``
    starts a stage). ``mode``: "bar", a live line per stage on a terminal (what it does, a bar and the count
    where they are known, the time spent and, where counted, left), each left standing when it ends; "log",
    one plain line per stage as it ends (what it did, its count, the time spent); "off": nothing.
    Once told what the stages still to come are expected to take (:meth:`expect`), each line also says about
    how long the whole run has left. ``console``: the Rich console of the bar (default: stderr's)."""

    def __init__(self, mode: str, console=None):
        self.mode, self._console = mode, console
        self._bar = self._task = self._stage = None
        self._done, self._total, self._start = 0, None, 0.0
        self._note = ""
        self._expected: dict[str, float] = {}  # stage → seconds it is expected to take
        self._took: dict[str, float] = {}  # stage → seconds it took, of the expected ones ended

    def expect(self, seconds: dict[str, float]) -> None:
        """The stages still to come (by name) and the seconds each is expected to take. The run's time left
        is then their sum, scaled by how much faster or slower than expected the stages ended so far went,
        less the time the stage in flight has run."""
        self._expected, self._took = dict(seconds), {}

    def time_left(self) -> float | None:
        """About how many seconds the run has left (None: no :meth:`expect`)."""
        if not self._expected:
            return None
        planned = sum(self._expected[stage] for stage in self._took)
        # this machine's and this recording's pace against the expectation, within 4x either way
        pace = min(max(sum(self._took.values()) / planned, 0.25), 4.0) if planned > 0 else 1.0
        left = sum(t for stage, t in self._expected.items() if stage not in self._took)
        if self._stage in self._expected and self._stage not in self._took:
            left -= min(self._expected[self._stage], (time.perf_counter() - self._start) / pace)
        return pace * max(left, 0.0)

    def _left_text(self) -> str:
        left = self.time_left()
        return "" if left is None else f"about {_duration(left)} left in all"

    def __enter__(self):
        if self.mode == "bar":
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
            from rich.table import Column

            self._bar = Progress(
                # the stage's name cut short before the bar, its count and its times are
                TextColumn("{task.description}", table_column=Column(max_width=36, no_wrap=True,
                                                                     overflow="ellipsis")),
                BarColumn(bar_width=20), TextColumn("{task.fields[count]}"), TimeElapsedColumn(),
                TimeRemainingColumn(), _run_left_column(self),
                console=self._console or Console(stderr=True), transient=False,
            )  # fmt: skip
            self._bar.start()
        return self

    def __call__(self, done: int, total: int | None, stage: str | None = None) -> None:
        if self.mode == "off":
            return
        if stage is not None and stage != self._stage:
            self._end()
            self._stage, self._start, self._note = stage, time.perf_counter(), ""
            if self._bar is not None:
                self._task = self._bar.add_task(stage, total=total, count="")
        self._done, self._total = done, total
        if self._bar is not None and self._task is not None:
            count = f"{done}/{total}" if total else ""
            self._bar.update(self._task, completed=done, total=total, count=count)

    def note(self, text: str) -> None:
        """What the stage in flight found (e.g. ``30 of 54 kept``), shown after its name."""
        if self.mode == "off" or self._stage is None:
            return
        self._note = text
        if self._bar is not None and self._task is not None:
            count = f"{self._done}/{self._total} " if self._total else ""
            self._bar.update(self._task, count=f"{count}({text})")

    def _end(self, stopped: bool = False) -> None:
        """End the stage in flight: complete, or ``stopped`` before its end."""
        if self._stage is None:
            return
        if self._stage in self._expected and not stopped:
            self._took[self._stage] = time.perf_counter() - self._start
        if self._bar is not None:  # the stage's line stays, with its time (and full where complete)
            if not stopped:
                self._bar.update(self._task, total=self._total or 1, completed=self._total or 1)
            self._bar.stop_task(self._task)
            self._bar.refresh()
        else:
            count = f", {self._done} of {self._total}" if self._total else ""
            elapsed = time.perf_counter() - self._start
            ended = f"stopped after {elapsed:.1f} s" if stopped else f"{elapsed:.1f} s"
            note = f" ({self._note})" if self._note else ""
            left = self._left_text() if not stopped and self.time_left() else ""
            ended += f"; {left}" if left else ""
            print(f"{self._stage}{count}{note}: {ended}", file=sys.stderr, flush=True)
        self._stage = None

    def stopped(self) -> None:
        """The run was stopped (a signal): the stage in flight ends as stopped."""
        self._end(stopped=True)

    def __exit__(self, kind, *exc) -> None:
        if kind is None or issubclass(kind, KeyboardInterrupt):  # done, or stopped by a second signal
            self._end(stopped=kind is not None)
        self._stage = None  # an error: its own line says what went wrong
        if self._bar is not None:
            self._bar.stop()


def _duration(seconds: float) -> str:
    """A time left, as a person reads it: ``40 s``, ``3 min``, ``1 h 10 min``."""
    if seconds < 90:
        return f"{max(5 * round(seconds / 5), 5):.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60} min"


def _run_left_column(owner: StageProgress):
    """A Rich column showing the whole run's time left (:meth:`StageProgress.time_left`), worked out anew
    at each refresh, on the line of the stage in flight only."""
    from rich.progress import ProgressColumn
    from rich.text import Text

    class RunLeft(ProgressColumn):
        def render(self, task) -> Text:
            in_flight = not task.finished and task.id == owner._task
            return Text(owner._left_text() if in_flight else "", style="progress.remaining")

    return RunLeft()
