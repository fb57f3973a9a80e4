"""Read a stream ahead in a background thread, so that producing frame i + 1 overlaps consuming frame i.

A landmark source's work — camera read, dot detection (OpenCV) and back-projection (a Warp kernel) —
releases Python's GIL for most of its time, as do the transfer kernel and the copies of the consumer.
Running the source in a second thread therefore puts the second CPU core to work: the frame rate is
bound by the slower of the two sides (and by the code that holds the GIL), not by their sum. The
CPU time per frame is unchanged.

Frames arrive in order and unchanged. An exception in the producer is raised in the consumer at the
position of the stream where it happened; a consumer that stops early (``break``, Ctrl-C, an
exception) stops the producer, which closes the upstream iterator in its own thread.
"""

from __future__ import annotations

import queue
import threading
from typing import Iterable, Iterator

from .._validate import as_count

__all__ = ["PrefetchedSource", "prefetch"]

_ITEM, _END, _ERROR = range(3)
_POLL_SECONDS = 0.05  # how often a blocked producer checks whether the consumer has gone
_JOIN_SECONDS = 5.0  # longest wait for the producer when the consumer stops


def prefetch(items: Iterable, *, depth: int = 2) -> Iterator:
    """Iterate ``items`` in a background thread, at most ``depth`` items ahead of the consumer.

    Args:
        items: any iterable (e.g. a source's ``frames()``); it is iterated, and closed, only in the
            background thread.
        depth: items held ready, ≥ 1 (two suffice to keep both threads busy).

    Yields:
        The items of ``items``, in order.

    Raises:
        ValueError: ``depth`` is not a positive integer.
        Whatever iterating ``items`` raises, when the consumer reaches that point of the stream.
    """
    depth = as_count(depth, "depth", minimum=1, maximum=1024)
    return _prefetched(items, depth)


def _prefetched(items: Iterable, depth: int) -> Iterator:
    ready: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def hand_over(entry) -> bool:
        """Queue ``entry`` unless the consumer has stopped; False once it has."""
        while not stop.is_set():
            try:
                ready.put(entry, timeout=_POLL_SECONDS)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        iterator = None
        try:
            iterator = iter(items)
            for item in iterator:
                if not hand_over((_ITEM, item)):
                    return
            hand_over((_END, None))
        except BaseException as error:  # handed to the consumer, which raises it
            hand_over((_ERROR, error))
        finally:
            close = getattr(iterator, "close", None)
            if close is not None:
                close()

    thread = threading.Thread(target=produce, name="warpface-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            kind, value = ready.get()
            if kind == _END:
                return
            if kind == _ERROR:
                raise value
            yield value
    finally:
        stop.set()
        # Free a producer blocked on a full queue and wait for it to close the upstream iterator; one
        # blocked inside the upstream (a camera that stopped delivering) is left to finish on its own.
        waited = 0.0
        while thread.is_alive() and waited < _JOIN_SECONDS:
            try:
                ready.get_nowait()
            except queue.Empty:
                thread.join(_POLL_SECONDS)
                waited += _POLL_SECONDS


class PrefetchedSource:
    """A landmark source whose :meth:`frames` are read ahead by :func:`prefetch`; every other
    attribute (``landmark_names``, ``close`` …) is the wrapped source's.

    Args:
        source: any landmark source (an object with ``frames()``).
        depth: frames held ready, ≥ 1.
    """

    def __init__(self, source, *, depth: int = 2):
        if not callable(getattr(source, "frames", None)):
            raise TypeError(f"source: expected a landmark source with frames(), got {type(source).__name__}")
        self.source = source
        self.depth = as_count(depth, "depth", minimum=1, maximum=1024)

    def frames(self) -> Iterator:
        """The wrapped source's frames, produced in a background thread."""
        return _prefetched(self.source.frames(), self.depth)

    def __getattr__(self, name: str):
        if name == "source":  # not yet set (during unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.source, name)
