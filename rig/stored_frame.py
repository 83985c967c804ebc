"""One recorded frame as stored (:class:`StoredFrame`): its bytes as the camera or the file
held them, or the decoded image of a bag's raw frame; decoded only after its header's size is
checked (an image bomb is never allocated)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.errors import RecordingError
from rig.image_size import declared_size, size_problem

__all__ = ["StoredFrame"]


@dataclass(frozen=True, eq=False)
class StoredFrame:
    """One recorded frame as stored: ``format`` ``jpeg``/``png`` with its ``raw`` bytes, or
    ``bgr`` with only a decoded ``image`` (gray (H, W) or BGR (H, W, 3) uint8: frames a bag
    holds as raw pixels). ``source`` names it in messages (file, or bag and topic)."""

    format: str
    raw: bytes | None = None
    image: NDArray[Any] | None = None
    source: str = ""

    def declared_size(self) -> tuple[int, int]:
        """(width, height) of the frame, from its header when encoded (nothing is decoded);
        RecordingError naming the source when the header cannot be read."""
        if self.image is not None:
            return int(self.image.shape[1]), int(self.image.shape[0])
        try:
            return declared_size(self.raw or b"", self.format)
        except ValueError as err:
            raise RecordingError(f"{self.source or 'frame'}: not a readable image ({err})") from None

    def decoded(self, expected_size: tuple[int, int] | None = None) -> NDArray[Any]:
        """The image as OpenCV decodes it (``IMREAD_UNCHANGED``); RecordingError naming the
        source when the bytes are not an image, or their header declares another size than
        ``expected_size`` (width, height; without one, beyond any camera's): checked before
        decoding, so a small file declaring a huge image is never allocated."""
        if self.image is not None:
            return self.image
        data = self.raw or b""
        problem = size_problem(data, self.format, expected_size) if data else "empty"
        if problem is not None:
            raise RecordingError(f"{self.source or 'frame'}: not a readable image ({problem})")
        img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise RecordingError(f"{self.source or 'frame'}: not a readable image")
        return np.asarray(img)

    def pipeline_image(self, expected_size: tuple[int, int] | None = None) -> NDArray[np.uint8]:
        """The image as the depth pipeline takes frames: uint8 gray or BGR (16-bit scaled to
        8, alpha dropped); ``expected_size`` as for :meth:`decoded`."""
        img = self.decoded(expected_size)
        if img.dtype == np.uint16:
            img = (img >> 8).astype(np.uint8)
        if img.ndim == 3 and img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
        elif img.ndim == 3 and img.shape[2] == 1:
            img = img[:, :, 0]
        return np.asarray(img, dtype=np.uint8)
