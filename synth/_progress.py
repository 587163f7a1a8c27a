"""A progress bar on stderr for loops over frames: a thin wrapper over tqdm."""

from __future__ import annotations

import sys

from tqdm import tqdm

__all__ = ["Progress"]


class Progress:
    """A bar of ``total`` steps labelled ``label`` on stderr (silent when not ``enabled``).

    Call :meth:`update` after each step; the bar closes itself (its last line ends) once
    ``total`` steps are done, or on :meth:`close`. Also a context manager that closes it.
    """

    def __init__(self, total: int, label: str, enabled: bool = True, unit: str = "frames"):
        self.total, self.label, self.enabled = total, label, enabled
        self.n = 0
        self._bar = tqdm(total=total, desc=label, unit=unit, disable=not enabled,
                         file=sys.stderr, dynamic_ncols=True)

    def update(self, n: int = 1) -> None:
        self.n += n
        self._bar.update(n)
        if self.n >= self.total:
            self.close()

    def close(self) -> None:
        self._bar.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
