"""The progress bar of ``register_many(..., progress=True)``: tqdm's when tqdm is installed,
else one line on stderr, redrawn at most five times a second, with the rate and time left."""

from __future__ import annotations

import sys
import time
from typing import Any


class ProgressBar:
    """Called as ``bar(done, total)`` after each pair; closes itself when done == total."""

    def __init__(self, total: int, label: str) -> None:
        self.total = total
        self.label = label
        self.start = time.monotonic()
        self.first: int | None = None  # pairs done at the first call (failed before starting)
        self.drawn = 0.0
        self.tqdm: Any = None
        try:
            from tqdm.auto import tqdm  # type: ignore[import-not-found,import-untyped,unused-ignore]

            self.tqdm = tqdm(total=total, desc=label, unit="pair")
        except ImportError:
            pass

    def __call__(self, done: int, total: int) -> None:
        if self.tqdm is not None:
            self.tqdm.update(done - self.tqdm.n)
            if done >= total:
                self.tqdm.close()
            return
        now = time.monotonic()
        if self.first is None:
            self.first, self.start = done, now
        if done < total and now - self.drawn < 0.2:
            return
        self.drawn = now
        elapsed = now - self.start
        rate = (done - self.first) / elapsed if elapsed > 0 else 0.0
        left = f"{(total - done) / rate:.0f} s left" if rate > 0 else "? left"
        end = "\n" if done >= total else ""
        sys.stderr.write(
            f"\r{self.label}: {done}/{total} pairs, {rate:.2f} pairs/s, {left}   {end}"
        )
        sys.stderr.flush()
