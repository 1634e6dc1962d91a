"""Progress over a known list of slow items (objects being trained or rendered), on stderr.

The first run of the main job trains the default pose models, a minute or two on an idle
machine and much longer on a loaded one; a user must see what is being built, how far it is
and how long is left. On a terminal that is a tqdm bar (elapsed time and estimate included);
elsewhere (a log file, CI, a pipe) a bar's carriage returns make an unreadable log, so each
finished item gets a line of its own instead. It lives in its own module, not in
``perception.training``, because that module's source is part of the default models' cache
key: a change to how progress looks must not retrain anyone's models.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from tqdm import tqdm


def _clock(seconds: float) -> str:
    """``m:ss`` (or ``h:mm:ss``), as tqdm writes times."""
    s = int(round(seconds))
    h, rest = divmod(s, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class ItemProgress:
    """Count ``total`` named items as they finish; say which one finished and when the rest
    will be done.

    ``enabled=False`` prints nothing. ``stream`` (default ``sys.stderr``) gets a tqdm bar when
    it is a terminal, else one line per finished item: ``desc: 3/11 banana (fit 12.0 s) -
    0:41 elapsed, about 1:49 left``. Use as a context manager, calling :meth:`update` per item.
    """

    def __init__(
        self,
        desc: str,
        total: int,
        enabled: bool = True,
        stream: TextIO | None = None,
        unit: str = "object",
    ) -> None:
        self.desc = desc
        self.total = int(total)
        self.enabled = bool(enabled)
        self.stream = stream if stream is not None else sys.stderr
        self.done = 0
        self._start = time.perf_counter()
        is_tty = getattr(self.stream, "isatty", lambda: False)()
        self._bar = (
            tqdm(total=self.total, desc=desc, unit=unit, file=self.stream, dynamic_ncols=True)
            if self.enabled and is_tty
            else None
        )

    @property
    def interactive(self) -> bool:
        """Whether a bar is shown (on a terminal): nested bars (rendering) make sense then."""
        return self._bar is not None

    def update(self, item: str, note: str = "") -> None:
        """``item`` has finished (``note``: what it took, e.g. its timings)."""
        self.done += 1
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.set_postfix_str(f"{item} done", refresh=False)
            self._bar.update(1)
            return
        elapsed = time.perf_counter() - self._start
        left = elapsed / self.done * (self.total - self.done)
        what = f"{item} ({note})" if note else item
        when = f"{_clock(elapsed)} elapsed" + (
            f", about {_clock(left)} left" if self.done < self.total else ""
        )
        print(f"{self.desc}: {self.done}/{self.total} {what} - {when}", file=self.stream)
        self.stream.flush()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> ItemProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
