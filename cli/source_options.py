"""Options naming what a recording is when it is a ROS bag: its two image topics and the pairing
gate, shared by ``rig process``, ``rig export mcap`` and ``rig serve --recording``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from rig.capture.recorded import RecordedPairs

__all__ = [
    "LeftTopicOption",
    "MaxSkewOption",
    "RightTopicOption",
    "TopicOption",
    "open_source",
    "parse_topics",
]

LeftTopicOption = Annotated[
    str | None,
    typer.Option(
        "--left-topic",
        metavar="TOPIC",
        help="A ROS bag's image topic of the left camera (e.g. /cam0/image_raw).",
    ),
]
RightTopicOption = Annotated[
    str | None,
    typer.Option("--right-topic", metavar="TOPIC", help="A ROS bag's image topic of the right camera."),
]
TopicOption = Annotated[
    list[str] | None,
    typer.Option(
        "--topic",
        metavar="CAMERA=TOPIC",
        help="A ROS bag's image topic of one camera of a rig of N cameras (repeat per camera).",
    ),
]
MaxSkewOption = Annotated[
    float | None,
    typer.Option(
        "--max-skew-ms",
        metavar="MS",
        min=0.0,
        help="A bag's pairing gate on header stamps.",
        show_default="half a frame period",
    ),
]


def parse_topics(values: list[str] | None) -> tuple[tuple[str, str], ...] | None:
    """``["cam1=/cam1/image_raw", ...]`` as (camera, topic) pairs (None: none given);
    ConfigError naming --topic otherwise."""
    from rig.errors import ConfigError

    if not values:
        return None
    out: dict[str, str] = {}
    for value in values:
        camera, sep, topic = value.partition("=")
        if not sep or not camera or not topic:
            raise ConfigError(f"--topic must look like CAMERA=TOPIC (cam1=/cam1/image_raw), got {value!r}")
        if camera in out:
            raise ConfigError(f"--topic: camera {camera!r} is named twice")
        out[camera] = topic
    return tuple(out.items())


def open_source(
    recording: Path,
    left_topic: str | None,
    right_topic: str | None,
    max_skew_ms: float | None,
    topics: tuple[tuple[str, str], ...] | None = None,
) -> RecordedPairs:
    """A recording directory, or a ROS bag (MCAP, .db3, bag directory) with its two image topics
    (or a topic per camera of a rig)."""
    from rig.capture.recorded import open_recording

    return open_recording(
        recording,
        left_topic=left_topic,
        right_topic=right_topic,
        max_skew_ms=max_skew_ms,
        topics=None if topics is None else dict(topics),
    )
