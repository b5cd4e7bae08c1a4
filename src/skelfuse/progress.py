"""A small progress bar for long evaluations, written to stderr so stdout stays clean for ``--json``.

It draws only when its stream is a terminal (or when forced), redraws at most every ``min_interval_s``, and
says nothing when quiet: logs and CI output are not filled with carriage returns.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


def note(text: str) -> None:
    """A status line on stderr, flushed at once: stdout holds the command's results."""
    print(text, file=sys.stderr, flush=True)


class Progress:
    """A one-line progress bar: ``label [#####-----] 12/24  50%  0:42 left``.

    Parameters
    ----------
    total : int
        Number of steps to completion.
    label : str
        Text in front of the bar.
    enabled : bool or None
        True forces drawing, False silences it, None draws only when ``stream`` is a TTY.
    stream : text stream or None
        Where to draw; standard error by default.
    min_interval_s : float
        Minimum time between redraws (the last step always draws).
    clock : callable
        Time source in seconds (injected by tests).

    Attributes
    ----------
    done : int
        Steps completed so far.
    """

    def __init__(
        self,
        total: int,
        label: str = "",
        *,
        enabled: bool | None = None,
        stream: TextIO | None = None,
        width: int = 30,
        min_interval_s: float = 0.1,
        clock=time.monotonic,
    ) -> None:
        if total < 0:
            raise ValueError(f"progress total must be >= 0, got {total}")
        self.total = int(total)
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        if enabled is None:
            isatty = getattr(self.stream, "isatty", None)
            enabled = bool(isatty and isatty())
        self.enabled = enabled
        self.width = width
        self.min_interval_s = min_interval_s
        self._clock = clock
        self._start = clock()
        self._last_draw = -float("inf")
        self.done = 0
        self._drawn = False

    def __enter__(self) -> Progress:
        self._draw(force=True)
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def update(self, n: int = 1, note: str = "") -> None:
        """Mark ``n`` more steps done; ``note`` is shown after the bar (e.g. the current take)."""
        self.done = min(self.total, self.done + n)
        self._draw(force=self.done >= self.total, note=note)

    def render(self, note: str = "") -> str:
        """The bar as text (without carriage return)."""
        frac = self.done / self.total if self.total else 1.0
        filled = round(frac * self.width)
        bar = "#" * filled + "-" * (self.width - filled)
        elapsed = self._clock() - self._start
        if 0 < self.done < self.total:
            eta = f"{_fmt_s(elapsed / self.done * (self.total - self.done))} left"
        else:
            eta = f"{_fmt_s(elapsed)} elapsed"
        text = f"{self.label} [{bar}] {self.done}/{self.total} {frac:4.0%} {eta}"
        return f"{text}  {note}" if note else text

    def _draw(self, *, force: bool = False, note: str = "") -> None:
        if not self.enabled:
            return
        now = self._clock()
        if not force and now - self._last_draw < self.min_interval_s:
            return
        self._last_draw = now
        self.stream.write("\r" + self.render(note).ljust(100)[:140])
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        """Finish the line so later output starts on a fresh one."""
        if self.enabled and self._drawn:
            self._draw(force=True)
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False


def _fmt_s(seconds: float) -> str:
    seconds = int(max(seconds, 0.0))
    return f"{seconds // 60}:{seconds % 60:02d}"
