"""Documents made once per state they describe: ``/calibration`` is built on its first request and
again only when the pair in effect has another calibration. The memo compares the state object
itself (``is``), so a new state is never served an old document."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["DocumentMemo"]

T = TypeVar("T")


class DocumentMemo:
    """Named documents, each held with the state object it was made from."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._docs: dict[str, tuple[object, Any]] = {}

    def get(self, name: str, state: object, build: Callable[[], T]) -> T:
        """The document ``name`` made from ``state``: the held one when it was made from this very
        object, else ``build()`` (held from now on)."""
        with self._lock:
            held = self._docs.get(name)
        if held is not None and held[0] is state:
            doc: T = held[1]
            return doc
        doc = build()
        with self._lock:
            self._docs[name] = (state, doc)
        return doc
