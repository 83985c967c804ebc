"""The size an encoded frame declares, read from its header before anything decodes it.

A JPEG's SOF marker and a PNG's IHDR chunk state the image's size, and a decoder allocates that
much before it reads a single pixel: a 20 KB file whose header says 30000×30000 costs 900 MB
gray, 2.7 GB in colour. So a frame's declared size is read first (Pillow's JPEG and PNG plugins
parse the header only; building the plugin's image object directly skips Pillow's own
decompression-bomb check, which would warn or refuse by its own pixel count) and refused when it
is not the camera's size, or, where that is not known, beyond :data:`MAX_FRAME_SIDE`.
"""

from __future__ import annotations

import io
import struct

from PIL import JpegImagePlugin, PngImagePlugin

__all__ = ["MAX_FRAME_SIDE", "declared_size", "size_problem"]

#: The largest frame side any camera configuration allows (``cameras.*.width/height``).
MAX_FRAME_SIDE = 8192

_PLUGINS = {"jpeg": JpegImagePlugin.JpegImageFile, "png": PngImagePlugin.PngImageFile}
# What Pillow's header parsers raise on bytes they cannot read (SyntaxError: "not a JPEG file").
_HEADER_ERRORS = (SyntaxError, OSError, ValueError, EOFError, IndexError, struct.error)


def declared_size(data: bytes, fmt: str) -> tuple[int, int]:
    """(width, height) the header of ``data`` (``jpeg`` or ``png``) declares; ValueError saying
    why when the header cannot be read."""
    plugin = _PLUGINS.get(fmt)
    if plugin is None:
        raise ValueError(f"no header to read for {fmt!r} frames")
    try:
        with plugin(io.BytesIO(data)) as image:
            width, height = image.size
    except _HEADER_ERRORS as err:
        raise ValueError(f"{fmt} header unreadable ({err})") from None
    return int(width), int(height)


def size_problem(data: bytes, fmt: str, expected: tuple[int, int] | None) -> str | None:
    """Why ``data`` must not be decoded: its header unreadable, its declared size other than
    ``expected`` (width, height), or, with no expectation, a side beyond :data:`MAX_FRAME_SIDE`;
    None when it may be."""
    try:
        width, height = declared_size(data, fmt)
    except ValueError as err:
        return str(err)
    declared = f"{fmt} header declares {width}x{height}"
    if expected is not None:
        if (width, height) != tuple(expected):
            return f"{declared}, the camera's frames are {expected[0]}x{expected[1]}"
    elif max(width, height) > MAX_FRAME_SIDE or min(width, height) < 1:
        return f"{declared}, beyond the {MAX_FRAME_SIDE} px a camera's frame may have"
    return None
