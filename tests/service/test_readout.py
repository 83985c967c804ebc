"""Reading metres off the service: ``/depth/colorbar`` is the scale ``/depth/colorized`` and ``rig
process --preview`` draw with (server.color_range_m, rig.colormap), and ``/depth/at`` gives one
pixel's range, depth, disparity and confidence of the frame it names, exactly as the arrays have
them; a pixel outside the view is a 422 naming the size."""

from __future__ import annotations

import io

import cv2
import httpx
import numpy as np
import pytest

from rig.colormap import DEFAULT_RANGE_M, DepthColors
from service.encoders import colorize_depth
from service.settings import load_settings
from tests.helpers.service import StartServer


def test_the_colour_scale_is_one_for_the_service_and_the_preview() -> None:
    assert load_settings(None).server.color_range_m == DEFAULT_RANGE_M
    depth = np.array([[0.4, 1.0, 3.0, np.nan]], np.float32)
    assert np.array_equal(colorize_depth(depth, *DEFAULT_RANGE_M), DepthColors().colorize(depth))


def test_colorbar_and_the_value_at_a_pixel(start_server: StartServer) -> None:
    with httpx.Client(timeout=30) as client:  # keep-alive: five requests within one frame
        check_colorbar_and_values(start_server, client)


def check_colorbar_and_values(start_server: StartServer, client: httpx.Client) -> None:
    live = start_server(color_range_m=[0.5, 20.0], fps=2.0)  # slow frames: room to ask about one
    url = live.base_url
    scale = httpx.get(url + "/depth/colorbar").json()
    colors = DepthColors(0.5, 20.0)
    assert (scale["near_m"], scale["far_m"], scale["scale"]) == (0.5, 20.0, "log")
    assert scale["palette"] == [f"#{r:02x}{g:02x}{b:02x}" for r, g, b in colors.palette().tolist()]
    assert [t["label"] for t in scale["ticks"]] == ["0.5 m", "1 m", "2 m", "5 m", "10 m", "20 m"]
    assert [t["position"] for t in scale["ticks"]] == pytest.approx(
        [float(colors.position(m)) for m in colors.ticks()]
    )
    # /depth/colorized draws with that scale (JPEG: within its loss).
    for _ in range(20):
        jpeg, npy = httpx.get(url + "/depth/colorized"), httpx.get(url + "/depth?format=npy")
        if jpeg.headers["X-Frame-Seq"] == npy.headers["X-Frame-Seq"]:
            break
    shown = cv2.imdecode(np.frombuffer(jpeg.content, np.uint8), cv2.IMREAD_COLOR).astype(int)
    expected = colors.colorize(np.load(io.BytesIO(npy.content))).astype(int)
    assert np.median(np.abs(shown - expected)) <= 3

    # The value at a pixel, as the frame's arrays have it.

    def same_frame(u: int, v: int) -> tuple[dict[str, object], dict[str, np.ndarray]]:
        """/depth/at (u, v) and the four arrays, all of one frame."""
        for _ in range(50):
            at = client.get(url + "/depth/at", params={"u": u, "v": v})
            names = ("range", "depth", "disparity", "confidence")
            arrays = {k: client.get(f"{url}/{k}?format=npy") for k in names}
            if {r.headers["X-Frame-Seq"] for r in arrays.values()} == {at.headers["X-Frame-Seq"]}:
                return at.json(), {k: np.load(io.BytesIO(r.content)) for k, r in arrays.items()}
        raise AssertionError("no /depth/at answer and arrays of one frame in 50 tries")

    _, values = same_frame(0, 0)
    rows, cols = np.nonzero(np.isfinite(values["range"]))
    valid = (int(cols[len(cols) // 2]), int(rows[len(rows) // 2]))
    rows, cols = np.nonzero(~np.isfinite(values["range"]))
    invalid = (int(cols[0]), int(rows[0]))
    for u, v in (valid, invalid):
        got, values = same_frame(u, v)
        assert (got["u"], got["v"]) == (u, v)
        for key, name in (("range_m", "range"), ("depth_m", "depth"), ("disparity_px", "disparity")):
            want = values[name][v, u]
            assert got[key] == (float(want) if np.isfinite(want) else None), key
        assert got["confidence"] == float(values["confidence"][v, u])
    assert httpx.get(url + "/depth/at", params={"u": valid[0], "v": valid[1]}).json()["range_m"] > 0

    height, width = values["range"].shape
    r = httpx.get(url + "/depth/at", params={"u": width, "v": 0})
    assert (
        r.status_code == 422
        and r.json()["detail"] == f"pixel ({width}, 0) is outside the {width}x{height} rectified view"
    )
    assert httpx.get(url + "/depth/at", params={"u": 3}).status_code == 422
