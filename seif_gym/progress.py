"""Progress of seif_gym's long commands, on stderr: tqdm when it is installed, else a line now and then.

``tqdm`` is optional (it comes with the ``train`` extra); without it a plain
line is written at every tenth of the work (and at least every 30 s), so a
log file stays readable. Either way stdout keeps only the results.

>>> from seif_gym.progress import Progress
>>> with Progress(3, "episodes", enabled=False) as bar:
...     for _ in range(3):
...         bar.update(1, "last: 0.2 m")
>>> bar.done
3
"""

from __future__ import annotations

import sys
import time
from types import TracebackType
from typing import Any, TextIO

__all__ = ["Progress"]


class Progress:
    """A progress bar over ``total`` units of work, on stderr.

    Parameters
    ----------
    total : int
        Units of work (episodes, steps, ...); at least 1.
    desc : str
        What is counted, shown before the bar.
    enabled : bool
        ``False`` keeps it silent (the commands' ``--quiet``).
    unit : str
        Name of one unit.
    stream : file, optional
        Where to write (default ``sys.stderr``).

    Attributes
    ----------
    done : int
        Units finished so far.
    """

    #: Seconds between two plain lines at most (when tqdm is not installed).
    PLAIN_INTERVAL = 30.0

    def __init__(self, total: int, desc: str, *, enabled: bool = True, unit: str = "it",
                 stream: TextIO | None = None) -> None:  # fmt: skip
        if isinstance(total, bool) or not isinstance(total, int):
            raise TypeError(f"total must be an int, got {type(total).__name__}")
        if total < 1:
            raise ValueError(f"total must be at least 1, got {total}")
        self.total, self.desc, self.enabled, self.unit = total, str(desc), bool(enabled), str(unit)
        self.done = 0
        self._stream = stream
        self._bar: Any = None
        self._started = time.perf_counter()
        self._last_line = self._started
        self._next_tenth = 1
        if self.enabled:
            try:
                from tqdm import tqdm
            except ImportError:
                tqdm = None
            if tqdm is not None:
                self._bar = tqdm(total=total, desc=self.desc, unit=self.unit, file=self.stream, mininterval=0.5,
                                 smoothing=0.1, dynamic_ncols=True)  # fmt: skip

    @property
    def stream(self) -> TextIO:
        """The stream written to."""
        return self._stream if self._stream is not None else sys.stderr

    def update(self, count: int = 1, postfix: str = "") -> None:
        """``count`` more units are done; ``postfix`` is shown after the bar (e.g. the last result)."""
        self.done += int(count)
        if not self.enabled:
            return
        if self._bar is not None:
            if postfix:
                self._bar.set_postfix_str(postfix, refresh=False)
            self._bar.update(int(count))
            return
        now = time.perf_counter()
        tenth = 10 * self.done // self.total
        if tenth >= self._next_tenth or now - self._last_line >= self.PLAIN_INTERVAL or self.done >= self.total:
            self._next_tenth = tenth + 1
            self._last_line = now
            elapsed = now - self._started
            left = elapsed * (self.total - self.done) / self.done if self.done else float("nan")
            print(f"{self.desc}: {self.done}/{self.total} {self.unit} ({100 * self.done / self.total:3.0f}%), "
                  f"{elapsed:.0f} s, ~{left:.0f} s left" + (f"  {postfix}" if postfix else ""),
                  file=self.stream, flush=True)  # fmt: skip

    def write(self, message: str) -> None:
        """A line on the stream that does not break the bar (nothing when disabled)."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.write(message, file=self.stream)
        else:
            print(message, file=self.stream, flush=True)

    def close(self) -> None:
        """End the bar."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:  # fmt: skip
        self.close()
