"""Reading the next chunk while this one is processed: :func:`read_ahead`.

A streaming verb alternates between two kinds of work: decompressing and converting a window
of points (lazrs and numpy, which release the GIL) and reducing it (numpy sorts and scatters).
One after the other, a 2-core machine has a core idle during the reduction. With one window
read ahead in a thread, the two overlap: ``cloud downsample --voxel 1 --memory 2G`` of the
20 M-point LAZ of ``benchmarks/bench_streaming.py`` took 13.3 and 14.5 s with it, 16.6 and
15.3 s without (timed by hand with ``/usr/bin/time``, runs alternating; the benchmark itself
measures the whole against laspy and open3d, not this part). The window read ahead is one more in flight, which
:data:`~pointfield.streaming.memory.CHUNK_COPIES` counts.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator
from typing import TypeVar

Item = TypeVar("Item")

# How often a blocked producer looks whether the consumer has gone away, in seconds.
_POLL_SECONDS = 0.05


class _End:
    """What the reading thread sends last: ``error`` when reading failed, else None."""

    def __init__(self, error: BaseException | None = None):
        self.error = error


def read_ahead(items: Iterable[Item], depth: int = 1) -> Iterator[Item]:
    """``items``, in order, produced by a thread that stays ``depth`` items ahead.

    An exception raised while producing an item is raised here, in its place. Closing the
    iterator (or leaving the loop) stops the thread before the next item, and closes
    ``items`` there, in the thread that iterated it.
    """
    if depth < 1:
        raise ValueError(f"depth must be at least 1, got {depth}")
    produced: queue.Queue = queue.Queue(maxsize=depth)
    stopped = threading.Event()

    def send(message: object) -> bool:
        """Queue ``message`` unless the consumer stops first; whether it was queued."""
        while not stopped.is_set():
            try:
                produced.put(message, timeout=_POLL_SECONDS)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        iterator = iter(items)
        try:
            for item in iterator:
                if not send(item):
                    return
            send(_End())
        except BaseException as error:  # noqa: BLE001 - re-raised in the consumer's thread
            send(_End(error))
        finally:
            close = getattr(iterator, "close", None)
            if close is not None:
                close()

    thread = threading.Thread(target=produce, name="pointfield-read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            message = produced.get()
            if isinstance(message, _End):
                if message.error is not None:
                    raise message.error
                return
            yield message
    finally:
        stopped.set()
        thread.join()
