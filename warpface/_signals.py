"""Ctrl-C (SIGINT) at safe points: writers finish what they started, captures stop between frames.

Python raises :class:`KeyboardInterrupt` at whatever bytecode runs when SIGINT arrives — in the
middle of a file rename, a list update, a layer export. Code that must not be cut in half runs in
:func:`deferred_interrupts`; long loops that can stop cleanly between iterations use
:class:`InterruptRequest`. Both act only in the main thread (the only one Python delivers signals
to); elsewhere they change nothing.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

__all__ = ["deferred_interrupts", "InterruptRequest"]


def _can_handle_signals() -> bool:
    return threading.current_thread() is threading.main_thread()


def _restorable(handler):
    # A handler installed outside Python reads back as None and cannot be reinstalled.
    return signal.default_int_handler if handler is None else handler


@contextmanager
def deferred_interrupts():
    """Hold SIGINT while the block runs; deliver it (once) when the block ends.

    Nested uses hand a held signal outwards, so it arrives after the outermost block.
    """
    if not _can_handle_signals():
        yield
        return
    held = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, _restorable(previous))
        if held:
            signal.raise_signal(signal.SIGINT)  # runs the previous handler: KeyboardInterrupt by default


class InterruptRequest:
    """Turn the first Ctrl-C inside the ``with`` block into a request to stop at the next safe point.

    Inside the block, ``bool(request)`` (or :attr:`requested`) becomes True on the first SIGINT; the
    loop checks it between iterations and ends cleanly. A second Ctrl-C raises
    :class:`KeyboardInterrupt` at once (for a source that blocks), except inside
    :func:`deferred_interrupts` blocks, which still complete first.
    """

    def __init__(self):
        self.requested = False
        self._previous = None

    def __bool__(self) -> bool:
        return self.requested

    def _handle(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> "InterruptRequest":
        if _can_handle_signals():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, _restorable(self._previous))
            self._previous = None
