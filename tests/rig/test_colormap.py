"""The one colour scale of depth in metres (rig.colormap): turbo on log metres between a fixed near
and far, its palette, ticks and legend; ``rig process --preview`` draws with it."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from rig.colormap import DEFAULT_RANGE_M, DepthColors, colorize_depth, metres_label
from rig.outputs import depth_preview

TURBO = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None, :], cv2.COLORMAP_TURBO)[0]  # BGR


def test_near_is_turbos_red_end_far_its_blue_end_log_between_invalid_black() -> None:
    colors = DepthColors(0.3, 8.0)
    middle = math.sqrt(0.3 * 8.0)  # halfway on the log scale
    depth = np.array([[0.1, 0.3, middle, 8.0, 50.0, np.nan, 0.0, -1.0, np.inf]], np.float32)
    out = colors.colorize(depth)[0]
    assert out[0].tolist() == out[1].tolist() == TURBO[255].tolist()  # near and nearer
    assert out[3].tolist() == out[4].tolist() == TURBO[0].tolist()  # far and farther
    assert out[2].tolist() in (TURBO[127].tolist(), TURBO[128].tolist())
    assert all(px.tolist() == [0, 0, 0] for px in out[5:])
    assert float(colors.position(middle)) == pytest.approx(0.5)
    assert np.array_equal(colorize_depth(depth, 0.3, 8.0), colors.colorize(depth))


def test_palette_runs_from_near_to_far_in_rgb() -> None:
    colors = DepthColors()
    palette = colors.palette()
    assert palette.shape == (256, 3) and palette.dtype == np.uint8
    assert palette[0].tolist() == TURBO[255][::-1].tolist()  # RGB of the near end
    assert palette[-1].tolist() == TURBO[0][::-1].tolist()
    # Even in log metres: the palette's middle is the colour of the scale's middle.
    middle = colors.colorize(np.array([[math.sqrt(0.3 * 8.0)]], np.float32))[0, 0][::-1]
    assert np.abs(palette[127].astype(int) - middle.astype(int)).max() <= 12


@pytest.mark.parametrize(
    ("near", "far", "ticks"),
    [
        (0.3, 8.0, [0.3, 0.5, 1.0, 2.0, 5.0, 8.0]),
        (0.2, 20.0, [0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0]),
        (0.5, 3.0, [0.5, 1.0, 2.0, 3.0]),
        (1.0, 1.5, [1.0, 1.5]),
    ],
)
def test_ticks_are_the_ends_and_the_readable_1_2_5_steps(near: float, far: float, ticks: list[float]) -> None:
    colors = DepthColors(near, far)
    assert colors.ticks() == ticks
    positions = [float(colors.position(m)) for m in ticks]
    assert positions[0] == 0.0 and positions[-1] == 1.0 and positions == sorted(positions)


def test_labels_and_bad_ranges() -> None:
    assert [metres_label(m) for m in (0.3, 1.0, 12.0, 0.25)] == ["0.3 m", "1 m", "12 m", "0.25 m"]
    for near, far in ((0.0, 1.0), (2.0, 1.0), (1.0, 1.0)):
        with pytest.raises(ValueError, match="near < far"):
            DepthColors(near, far)


def test_the_preview_is_the_left_view_the_colour_depth_and_a_legend_in_metres() -> None:
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.2, 9.0, (240, 320)).astype(np.float32)
    depth[:, :40] = np.nan
    left = rng.integers(0, 256, (240, 320), dtype=np.uint8)
    preview = depth_preview(left, depth)
    assert preview.shape == (240, 320 + 320 + 72, 3)
    assert np.array_equal(preview[:, :320, 0], left)
    # The colours are the scale's, fixed (not stretched to this frame's depths).
    assert np.array_equal(preview[:, 320:640], DepthColors(*DEFAULT_RANGE_M).colorize(depth))
    legend = preview[:, 640:]
    colors = DepthColors()
    # The bar: near at the top, far at the bottom, evenly in log metres; a white tick mark at each
    # labelled distance, white label text beside it.
    metres = np.exp(np.linspace(math.log(colors.near_m), math.log(colors.far_m), 240)).astype(np.float32)
    expected = colors.colorize(metres[:, None])[:, 0]
    tick_rows = {round(float(colors.position(m)) * 239) for m in colors.ticks()}
    plain = [r for r in range(240) if r not in tick_rows]
    assert np.array_equal(legend[plain, 2], expected[plain])
    for row in tick_rows:
        assert (legend[row, 19] == 255).all(), row
    assert (legend[:, 24:] > 0).any(axis=2).sum() > 200  # the labels
