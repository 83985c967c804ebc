"""Recorded pairs from any source: a recording directory or a ROS bag, chosen once by content.

``open_recording(path)`` returns a :class:`~rig.recording.Recording` for a recording directory
(``recording.json``) and a :class:`~rig.capture.bag.BagRecording` for an MCAP file, a ROS 2
``.db3`` or bag directory, or a ROS 1 ``.bag`` (which need the two image topics). Both have
``root``, ``cameras``, ``pairs``, ``calibration_path`` and ``read_frame(pair, camera)``; the file
cameras, ``rig process`` and the MCAP export read only through those.
"""

from __future__ import annotations

import threading
import weakref
from pathlib import Path

from rig.capture.bag import BagRecording, is_bag
from rig.errors import RecordingError
from rig.recording import Recording

__all__ = ["RecordedPairs", "open_recording"]

RecordedPairs = Recording | BagRecording

# Both file cameras of a bag replay share one index (indexing reads the whole bag).
_BAGS: weakref.WeakValueDictionary[tuple[object, ...], BagRecording] = weakref.WeakValueDictionary()
_BAGS_LOCK = threading.Lock()


def open_recording(
    path: str | Path,
    *,
    left_topic: str | None = None,
    right_topic: str | None = None,
    max_skew_ms: float | None = None,
    topics: dict[str, str] | None = None,
) -> RecordedPairs:
    """The recording at ``path`` (see the module docstring); a bag's image topics are
    ``left_topic`` and ``right_topic``, or ``topics`` (camera → topic) for a rig of N cameras.
    RecordingError naming the path."""
    p = Path(path)
    named = topics is not None or left_topic is not None or right_topic is not None
    if not is_bag(p):
        if named:
            raise RecordingError(f"{p}: image topics name the topics of a ROS bag; this is not one")
        return Recording(p)
    if topics is None and (left_topic is None or right_topic is None):
        raise RecordingError(
            f"{p}: a ROS bag: name its two image topics (--left-topic and --right-topic, or the file "
            "cameras' left_topic and right_topic; a rig's: --topic CAMERA=TOPIC per camera)"
        )
    if topics is not None and (left_topic is not None or right_topic is not None):
        raise RecordingError(f"{p}: name a bag's topics per camera or as left and right, not both")
    chosen = topics if topics is not None else {"left": str(left_topic), "right": str(right_topic)}
    gate = None if max_skew_ms is None else round(max_skew_ms * 1e6)
    try:
        st = p.stat()
    except OSError as err:
        raise RecordingError(f"{p}: not found ({err.strerror})") from None
    key = (str(p.resolve()), st.st_mtime_ns, st.st_size, tuple(chosen.items()), gate)
    with _BAGS_LOCK:
        bag = _BAGS.get(key)
        if bag is None:
            bag = BagRecording(p, topics=chosen, max_skew_ns=gate)
            _BAGS[key] = bag
    return bag
