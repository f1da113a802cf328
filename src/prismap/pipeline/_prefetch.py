"""One frame ahead: the next frame's inputs computed in a background thread while this one is integrated.

Reading a frame (PNG decoding), matching it (OpenCV's matchers) and integrating it (the grid's compiled
kernels) all release the GIL, so the matcher of frame k + 1 runs beside the integration of frame k.
"""

from concurrent.futures import ThreadPoolExecutor

THREAD_NAME = "prismap-prefetch"
"""Name prefix of the look-ahead thread (what a test or a profiler looks for)."""


class Prefetch:
    """``(item, produce(item))`` over ``items`` in order, ``produce`` of the next item running in one background
    thread while the caller works on this one.

    At most one item is computed ahead, so memory holds two items' results at most. Whatever ``produce``
    raises for an item is raised, the same exception, when the iteration reaches that item (after the
    caller has finished with the items before it), and nothing is computed past it. Use as a context
    manager: leaving it (at the end, on an error, on KeyboardInterrupt) cancels the look-ahead that has not
    started and waits for the one running, so no thread outlives the ``with`` block.

    Parameters
    ----------
    produce : callable
        ``produce(item)``; runs in the background thread, one call at a time, in the order of ``items``.
    items : iterable
    """

    def __init__(self, produce, items):
        self._produce = produce
        self._items = list(items)
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix=THREAD_NAME)
        self._ahead = None

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        if self._ahead is not None:
            self._ahead.cancel()
            self._ahead = None
        self._thread.shutdown(wait=True)

    def __iter__(self):
        items = self._items
        if items:
            self._ahead = self._thread.submit(self._produce, items[0])
        for k, item in enumerate(items):
            future, self._ahead = self._ahead, None
            result = future.result()
            if k + 1 < len(items):
                self._ahead = self._thread.submit(self._produce, items[k + 1])
            yield item, result
