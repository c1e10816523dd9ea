"""Work a stage hands off and collects later, in order (ROS-free, no I/O).

A stage that can overlap part of its work with the rest of the graph keeps that part's state in
an object of its own (e.g. :class:`~.scanpair.ScalePairs`) and talks to it only by
``submit(method, *args)`` and, at a fixed later point, ``collect()`` (the oldest answer;
``ready()``: it is there). Where
the object lives is the caller's choice: :class:`Inline` here, in the stage's own process, or a
worker process (nodes/worker.py) with the same three calls. The answers and the points at
which the stage takes them do not depend on which, so neither do the results.
"""

from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any, Protocol


class Deferred(Protocol):
    kind: str

    def submit(self, method: str, *args) -> None: ...

    def collect(self) -> Any: ...

    def ready(self) -> bool: ...

    def close(self, timeout_s: float = 5.0) -> None: ...


class Inline:
    """The object in the caller's process: :meth:`submit` calls the method now and keeps the
    answer for :meth:`collect`."""

    kind = "inline"

    def __init__(self, obj: Any) -> None:
        self.obj = obj
        self._answers: collections.deque = collections.deque()

    def submit(self, method: str, *args) -> None:
        self._answers.append(getattr(self.obj, method)(*args))

    def collect(self) -> Any:
        return self._answers.popleft()

    def ready(self) -> bool:
        """:meth:`collect` would not wait."""
        return True

    def call(self, method: str, *args) -> Any:
        """``method(*args)`` now (nothing may be waiting to be collected)."""
        assert not self._answers, "call() with answers not collected"
        return getattr(self.obj, method)(*args)

    def close(self, timeout_s: float = 5.0) -> None:
        pass


#: how a stage builds the home of an object it hands work to: ``offload(cls, args)``
Offload = Callable[[type, tuple], Deferred]


def inline(cls: type, args: tuple) -> Inline:
    """The default :data:`Offload`: ``cls(*args)`` in this process."""
    return Inline(cls(*args))
