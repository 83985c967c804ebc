"""Does a calibration fit the cameras? A sanity check against real frames, run at start-up.

A wrong calibration does not fail: it gives wrong or no depth, quietly. Checked here, with the
likely cause named:

* **image size** — frames of another size than the calibration's (another camera mode, or the
  calibration of another camera): an error before anything is processed;
* **the pair's overlap** — each camera's share of the VPC its lookup table covers;
* **matched features** — SIFT features of the two rectified views matched (ratio test): in a
  rectified pair they lie on the same row (*vertical disparity* ≈ 0) and the left view sees
  them further right (*disparity* ≥ 0). When they do not, the pair is rectified once more with
  the two cameras' frames exchanged: if it fits then, the cameras are swapped (said so);
  otherwise rows apart mean the calibration does not fit the mount or the lenses, most matches
  at negative disparity a swap in the calibration itself, too few matches views that do not
  overlap (or a plain scene);
* **valid fraction** — the share of the VPC both cameras see (both lookup tables valid) with depth
  on the first pair: the rest of the VPC cannot have depth whatever the calibration (a lat-lon
  pair's is about 40 %), so counting it would call a correct calibration suspect.

:func:`check_calibration` returns :class:`Finding` s (``error``: stop; ``warning``: say once)
and the figures; ``rig process`` and ``rig export mcap`` run it on a recording's first readable
pair (:func:`check_recording`), ``rig serve`` on the first pair it processes, ``rig check`` on a
sample pair (see docs/calibration.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.rig import Rig
from rig.capture.recorded import RecordedPairs
from rig.errors import RecordingError, RigError
from rig.pipeline import DepthFrame, DepthPipeline

__all__ = [
    "CalibrationCheck",
    "Finding",
    "check_calibration",
    "check_frame_sizes",
    "check_recording",
    "matched_disparities",
]

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]

#: Fewer matched features than this: the scene or the overlap says too little to judge rows
#: (the median of the rows' differences is robust to a few wrong matches).
MIN_MATCHES = 20
#: Lowe's ratio test for a match to count, and SIFT's contrast threshold (below OpenCV's 0.04:
#: small, noisy views need the weaker features too).
RATIO = 0.8
CONTRAST = 0.02
#: Median |vertical disparity| (px) above which rows do not line up (warning), and far off (error).
VERTICAL_WARN_PX = 1.0
VERTICAL_ERROR_PX = 4.0
#: Share of matches at negative disparity that means the two views are swapped.
SWAPPED_SHARE = 0.6
#: Depth on less than this share of the VPC both cameras see, on the first pair, is worth a warning.
LOW_VALID = 0.25
#: A camera whose table covers less than this share of the VPC barely overlaps the other.
LOW_OVERLAP = 0.5
#: Pairs of a recording tried for its check before giving up on finding a readable one.
CHECK_TRIES = 10


@dataclass(frozen=True)
class Finding:
    severity: Literal["error", "warning"]
    message: str


@dataclass(frozen=True)
class CalibrationCheck:
    """The findings and the figures they came from (None: not measured)."""

    findings: list[Finding] = field(default_factory=list)
    matches: int | None = None
    vertical_px: float | None = None  # median |y_left - y_right| of the matches
    disparity_px: float | None = None  # median x_left - x_right
    negative_share: float | None = None  # share of matches at negative disparity
    valid_fraction: float | None = None  # of the VPC both cameras see
    overlap: dict[str, float] = field(default_factory=dict)

    @property
    def errors(self) -> list[Finding]:
        return [f for f in self.findings if f.severity == "error"]

    @property
    def warnings(self) -> list[Finding]:
        return [f for f in self.findings if f.severity == "warning"]


def check_frame_sizes(
    rig: Rig, sizes: Mapping[str, tuple[int, int]], source: str = "frames"
) -> list[Finding]:
    """An error per camera whose frames (width, height) differ from its calibration's."""
    out = []
    for name, (w, h) in sizes.items():
        model = rig.cameras[name]
        if (w, h) != (model.width, model.height):
            scale = w / model.width if model.width else 0.0
            hint = (
                f"a calibration made at another resolution (the frames are ×{scale:g} its size)"
                if abs(scale * model.height - h) < 1 and scale != 1
                else "a calibration of other cameras, or the cameras in another mode"
            )
            out.append(
                Finding(
                    "error",
                    f"camera {name}: the {source} are {w}x{h} but the calibration is for "
                    f"{model.width}x{model.height}: {hint}",
                )
            )
    return out


def matched_disparities(left: U8, right: U8, mask: U8 | None = None) -> tuple[F64, F64]:
    """Horizontal (x_left - x_right) and vertical (y_left - y_right) disparities (N,) of the
    SIFT features the two gray images share (ratio test, one match per right feature)."""
    sift = cv2.SIFT.create(nfeatures=2000, contrastThreshold=CONTRAST)
    kl, dl = sift.detectAndCompute(left, mask)
    kr, dr = sift.detectAndCompute(right, mask)
    if dl is None or dr is None or len(kl) < 2 or len(kr) < 2:
        return np.zeros(0), np.zeros(0)
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(dl, dr, k=2)
    best: dict[int, tuple[float, int]] = {}
    for m in pairs:
        if len(m) == 2 and m[0].distance < RATIO * m[1].distance:
            q, t = m[0].queryIdx, m[0].trainIdx
            if t not in best or m[0].distance < best[t][0]:
                best[t] = (m[0].distance, q)
    if not best:
        return np.zeros(0), np.zeros(0)
    pl = np.array([kl[q].pt for _, q in best.values()], dtype=np.float64)
    pr = np.array([kr[t].pt for t in best], dtype=np.float64)
    return pl[:, 0] - pr[:, 0], pl[:, 1] - pr[:, 1]


def _gray(image: U8) -> U8:
    return image if image.ndim == 2 else np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), np.uint8)


def _feature_findings(dx: F64, dy: F64) -> list[Finding]:
    n = dx.size
    if n < MIN_MATCHES:
        return [
            Finding(
                "warning",
                f"only {n} features match between the two rectified views: they barely overlap (the "
                "calibration does not fit these cameras, or belongs to another rig), or the scene is "
                "too plain to tell",
            )
        ]
    out = []
    negative = float(np.mean(dx < -0.5))
    if negative >= SWAPPED_SHARE:
        out.append(
            Finding(
                "error",
                f"{100 * negative:.0f} % of {n} matched features lie at negative disparity (median "
                f"{float(np.median(dx)):.1f} px): the left view sees the scene left of the right view's "
                "(left and right swapped in the config or the calibration)",
            )
        )
    vertical = float(np.median(np.abs(dy)))
    if vertical > VERTICAL_WARN_PX:
        severity: Literal["error", "warning"] = "error" if vertical > VERTICAL_ERROR_PX else "warning"
        out.append(
            Finding(
                severity,
                f"the rectified views' rows are {vertical:.1f} px apart (median of {n} matched features, "
                f"should be < {VERTICAL_WARN_PX:g}): the calibration does not fit these cameras (the mount "
                "moved, other lenses, or another rig's calibration); recalibrate the pair",
            )
        )
    return out


def _fits(dx: F64, dy: F64) -> bool:
    """Rows line up and disparities are positive: what a correct rectified pair shows."""
    return (
        dx.size >= MIN_MATCHES
        and float(np.median(np.abs(dy))) <= VERTICAL_WARN_PX
        and float(np.mean(dx < -0.5)) < 1.0 - SWAPPED_SHARE
    )


def _swapped(pipeline: DepthPipeline, left: U8, right: U8, mask: U8 | None, dy: F64) -> Finding | None:
    """An error if the pair fits with the two cameras' images exchanged (and does not as given)."""
    pair = pipeline.pair
    try:
        as_left = pipeline.rectify_camera(pair.left, right)[1]
        as_right = pipeline.rectify_camera(pair.right, left)[1]
    except RigError:  # the two cameras' frames differ in size: they cannot be exchanged
        return None
    sdx, sdy = matched_disparities(as_left, as_right, mask)
    if not _fits(sdx, sdy):
        return None
    given = f"{float(np.median(np.abs(dy))):.1f} px" if dy.size else "no rows to compare"
    return Finding(
        "error",
        f"cameras {pair.left} and {pair.right} are swapped: with their frames exchanged the rectified "
        f"rows line up ({float(np.median(np.abs(sdy))):.2f} px over {sdx.size} matched features, against "
        f"{given} as configured); exchange the two cameras' devices in the config (or plug them the "
        "other way round)",
    )


def check_calibration(
    pipeline: DepthPipeline, left: U8, right: U8, frame: DepthFrame | None = None
) -> CalibrationCheck:
    """Check the calibration of ``pipeline`` against one fisheye pair (``left``, ``right`` as the
    cameras deliver them, gray or BGR) and its processed ``frame`` (processed here if None):
    overlap, matched features, the swapped hypothesis, valid fraction. Sizes are
    :func:`check_frame_sizes`'s."""
    if frame is None:
        frame = pipeline.process(left, right)
    findings: list[Finding] = []
    overlap = dict(pipeline.valid_fraction)
    for name, share in overlap.items():
        if share < LOW_OVERLAP:
            findings.append(
                Finding(
                    "warning",
                    f"camera {name} sees only {100 * share:.0f} % of the VPC: the views barely overlap "
                    "(VPC direction or field of view, or a calibration of another rig)",
                )
            )
    mask = None
    left_lut, right_lut = (pipeline.luts[n] for n in pipeline.names)
    seen = left_lut.valid & right_lut.valid
    if overlap and min(overlap.values()) < 1.0:
        mask = (seen * 255).astype(np.uint8)
    dx, dy = matched_disparities(_gray(frame.left_rect), _gray(frame.right_rect), mask)
    if _fits(dx, dy):
        problems = []
    else:
        swapped = _swapped(pipeline, left, right, mask, dy)
        problems = [swapped] if swapped is not None else _feature_findings(dx, dy)
    findings += problems
    counted = frame.valid[seen] if seen.shape == frame.valid.shape and seen.any() else frame.valid
    valid = float(np.count_nonzero(counted)) / max(1, counted.size)
    if valid < LOW_VALID and not any(f.severity == "error" for f in findings):
        findings.append(
            Finding(
                "warning",
                f"only {100 * valid:.0f} % of the VPC both cameras see has depth on the first pair: a "
                "calibration that does not fit, a scene without texture, or covered lenses",
            )
        )
    return CalibrationCheck(
        findings,
        matches=int(dx.size),
        vertical_px=float(np.median(np.abs(dy))) if dy.size else None,
        disparity_px=float(np.median(dx)) if dx.size else None,
        negative_share=float(np.mean(dx < -0.5)) if dx.size else None,
        valid_fraction=valid,
        overlap=overlap,
    )


def check_recording(pipeline: DepthPipeline, recording: RecordedPairs) -> list[Finding]:
    """The calibration of ``pipeline`` against ``recording``'s first readable pair (of its first
    :data:`CHECK_TRIES`; none readable: no finding, the run reports every pair that is not): the
    frame sizes (:func:`check_frame_sizes`; frames of another size end the check), then
    :func:`check_calibration`, each of its messages naming the pair. What ``rig process`` and
    ``rig export mcap`` check before processing."""
    # A recording of the pair's own cameras (a ring's) is read by their names, else as left, right.
    named = all(n in recording.cameras for n in pipeline.names)
    columns = pipeline.names if named else ("left", "right")
    for pair in recording.pairs[:CHECK_TRIES]:
        try:  # the sizes from the headers: nothing of another size is decoded
            stored = recording.read_frame(pair, columns[0]), recording.read_frame(pair, columns[1])
            sizes = {
                pipeline.pair.left: stored[0].declared_size(),
                pipeline.pair.right: stored[1].declared_size(),
            }
        except RecordingError:
            continue
        wrong_size = check_frame_sizes(pipeline.rig, sizes, f"frames of {recording.root}")
        if wrong_size:
            return wrong_size
        try:
            left, right = (s.pipeline_image(sizes[n]) for s, n in zip(stored, pipeline.names, strict=True))
        except RecordingError:
            continue
        check = check_calibration(pipeline, left, right)
        return [
            Finding(f.severity, f"calibration check on pair {pair.seq}: {f.message}") for f in check.findings
        ]
    return []
