"""
Progress bars for the long commands (warmup, bench, render), quiet when not a terminal.

``bar(total, desc)`` returns a ``tqdm`` bar (``pip install '.[progress]'``) when the
stream is a terminal and tqdm is installed, else a silent stand-in with the same small
interface (``update``, ``set_postfix_str``, ``close``, context manager, iteration), so
logs, CI and pipes get no control characters. ``SM_ROS_PROGRESS=0`` silences the bars,
``=1`` forces them (e.g. under ``script``).
"""

import os
import sys
from typing import Iterable, Optional


class _Quiet:
    """The silent stand-in for a tqdm bar."""

    def __init__(self, iterable=None, total=None, **_):
        """Keep the iterable and count nothing else."""
        self.iterable = iterable
        self.total = total
        self.n = 0

    def __iter__(self):
        """Iterate over the wrapped iterable."""
        for item in self.iterable or ():
            self.n += 1
            yield item

    def update(self, n=1):
        """Count ``n`` more steps."""
        self.n += n

    def refresh(self):
        """Nothing to draw."""

    def set_postfix_str(self, *_a, **_k):
        """Ignore the postfix."""

    def set_description_str(self, *_a, **_k):
        """Ignore the description."""

    def close(self):
        """Nothing to close."""

    def __enter__(self):
        """Use as a context manager."""
        return self

    def __exit__(self, *exc):
        """Nothing to close."""


def enabled(stream=None) -> bool:
    """Return whether bars are drawn on ``stream`` (stderr by default)."""
    flag = os.environ.get('SM_ROS_PROGRESS', '').strip()
    if flag == '0':
        return False
    stream = sys.stderr if stream is None else stream
    if flag != '1':
        try:
            if not stream.isatty():
                return False
        except (AttributeError, ValueError):
            return False
    try:
        import tqdm  # noqa: F401
    except ImportError:
        return False
    return True


def bar(total: Optional[float] = None, desc: str = '', unit: str = 'it',
        iterable: Optional[Iterable] = None, stream=None, **kwargs):
    """Return a progress bar (tqdm on a terminal, else a silent stand-in)."""
    if not enabled(stream):
        return _Quiet(iterable=iterable, total=total)
    from tqdm import tqdm
    return tqdm(iterable=iterable, total=total, desc=desc, unit=unit, leave=False,
                file=sys.stderr if stream is None else stream, dynamic_ncols=True, **kwargs)
