"""Stereo pairs of a rig of N cameras from its geometry (rig.ring): neighbours by optical-axis
azimuth about the rig's up axis, oriented like the two-camera rig, kept where the lenses overlap;
an explicit list overrides."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.geometry import make_transform, rot_x, rot_y
from calibration.models import create
from calibration.rig import Rig
from rig.errors import ConfigError
from rig.rectified import rectified_frame
from rig.ring import adjacent_pairs, axis_azimuths, rig_up
from rig.sim import divergent_rig, get_preset
from rig.sim.mount import ring_rig
from rig.sim.presets import RING_PRESETS, get_ring_preset

RING = [("cam1", "cam2"), ("cam2", "cam3"), ("cam3", "cam4"), ("cam4", "cam1")]


def _moved(rig: Rig, T: np.ndarray, order: list[str] | None = None) -> Rig:
    """``rig`` with every camera moved by ``T`` (rig frame to rig frame), in ``order``."""
    names = order or rig.names
    return Rig({n: rig.cameras[n] for n in names}, {n: T @ rig.T_rig_cam[n] for n in names})


def _upright(rig: Rig, pairs: list[tuple[str, str]]) -> bool:
    """Every pair's rectified y points away from the rig's up (images upright)."""
    up = rig_up(rig)
    return all(float(rectified_frame(rig, a, b)[0][:, 1] @ up) < 0.0 for a, b in pairs)


@pytest.mark.parametrize("preset", ["prototype", "paper-sim"])
def test_two_cameras_give_todays_left_right(preset: str) -> None:
    rig = get_preset(preset).rig
    assert adjacent_pairs(rig) == [("left", "right")]
    assert rig_up(rig) == pytest.approx([0.0, -1.0, 0.0], abs=1e-12)
    # Listed the other way round, the pair keeps its orientation.
    swapped = _moved(rig, np.eye(4), ["right", "left"])
    assert adjacent_pairs(swapped) == [("left", "right")]


def test_ring4_pairs_each_camera_with_its_clockwise_neighbour() -> None:
    assert set(RING_PRESETS) == {"ring4"}
    rig = get_ring_preset("ring4").rig
    assert rig.names == ["cam1", "cam2", "cam3", "cam4"]
    assert adjacent_pairs(rig) == RING
    assert rig_up(rig) == pytest.approx([0.0, -1.0, 0.0], abs=1e-12)
    az = axis_azimuths(rig)
    assert [math.degrees(az[n]) for n in rig.names] == pytest.approx([0.0, 90.0, 180.0, 270.0], abs=1e-9)
    # Every adjacent pair is the prototype's pair: 72 mm, axes 90° apart, baseline square to their bisector.
    for a, b in RING:
        assert rig.baseline(a, b) == pytest.approx(0.072, abs=1e-12)
        assert math.degrees(math.acos(rig.axis(a) @ rig.axis(b))) == pytest.approx(90.0, abs=1e-9)
        assert (rig.center(b) - rig.center(a)) @ (rig.axis(a) + rig.axis(b)) == pytest.approx(0.0, abs=1e-12)
    assert _upright(rig, RING)


def test_camera_order_and_rig_frame_do_not_change_the_pairs() -> None:
    rig = get_ring_preset("ring4").rig
    # Listed from cam3: the order starts there, the pairs are the same.
    shuffled = _moved(rig, np.eye(4), ["cam3", "cam1", "cam4", "cam2"])
    assert adjacent_pairs(shuffled) == [
        ("cam3", "cam4"),
        ("cam4", "cam1"),
        ("cam1", "cam2"),
        ("cam2", "cam3"),
    ]
    # The rig frame turned and moved arbitrarily (e.g. a calibration that puts camera 1 at the origin).
    T = make_transform(rot_x(0.4) @ rot_y(-1.1), [0.3, -0.2, 0.5])
    moved = _moved(rig, T)
    assert adjacent_pairs(moved) == RING
    assert rig_up(moved) == pytest.approx(T[:3, :3] @ [0.0, -1.0, 0.0], abs=1e-12)


def test_up_is_the_axes_plane_normal_even_with_pitched_cameras() -> None:
    """Cameras looking 15° down (and one rolled) still have the vertical as up: the axes lie on a
    cone about it, whose best-fit plane's normal is its axis; the cameras' mean −y is not vertical."""
    base = get_ring_preset("ring4").rig
    pitched = {
        n: T @ make_transform(rot_x(math.radians(-15.0)), [0, 0, 0]) for n, T in base.T_rig_cam.items()
    }
    pitched["cam2"] = pitched["cam2"] @ make_transform(
        np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]), [0, 0, 0]
    )
    rig = Rig(dict(base.cameras), pitched)
    assert rig_up(rig) == pytest.approx([0.0, -1.0, 0.0], abs=1e-9)
    mean_up = -np.mean([T[:3, 1] for T in pitched.values()], axis=0)
    assert math.degrees(math.acos(mean_up[1] * -1.0 / np.linalg.norm(mean_up))) > 10.0
    assert adjacent_pairs(rig) == RING


def test_a_ring_of_three_closes_the_loop() -> None:
    left, right = (get_preset("prototype").rig.cameras[n] for n in ("left", "right"))
    rig = ring_rig([left, right, left], 0.1)
    pairs = adjacent_pairs(rig)
    assert pairs == [("cam1", "cam2"), ("cam2", "cam3"), ("cam3", "cam1")]
    assert _upright(rig, pairs)


def test_cameras_looking_in_are_oriented_upright() -> None:
    """Turned to look into the ring, each neighbour pair's baseline points the other way: the
    left camera is then the one of larger azimuth, so that the rectified images stay upright."""
    base = get_ring_preset("ring4").rig
    inward = Rig(
        dict(base.cameras),
        {n: T @ make_transform(rot_y(math.pi), [0, 0, 0]) for n, T in base.T_rig_cam.items()},
    )
    pairs = adjacent_pairs(inward)
    assert set(pairs) == {(b, a) for a, b in RING}
    assert _upright(inward, pairs)


def test_parallel_axes_fall_back_to_the_cameras_up() -> None:
    lens = get_preset("prototype").rig.cameras["left"]
    rig = Rig(
        {"right": lens, "left": lens.replace()},
        {"right": make_transform(np.eye(3), [0.06, 0, 0]), "left": make_transform(np.eye(3), [-0.06, 0, 0])},
    )
    assert rig_up(rig) == pytest.approx([0.0, -1.0, 0.0])
    assert adjacent_pairs(rig) == [("left", "right")]


def test_lenses_that_do_not_overlap_make_no_pair() -> None:
    narrow = create("pinhole", 640, 480, fx=400.0, fy=400.0, cx=319.5, cy=239.5)  # 77° across
    rig = ring_rig([narrow, narrow.replace(), narrow.replace(), narrow.replace()], 0.1)
    assert adjacent_pairs(rig) == []
    # Two of the prototype's lenses back to back overlap (190° each): one pair.
    lens = get_preset("prototype").rig.cameras["left"]
    assert len(adjacent_pairs(divergent_rig(lens, lens.replace(), 0.1, 170.0))) == 1


def test_explicit_pairs_override_and_are_checked() -> None:
    rig = get_ring_preset("ring4").rig
    assert adjacent_pairs(rig, [("cam2", "cam1"), ("cam1", "cam3")]) == [("cam2", "cam1"), ("cam1", "cam3")]
    bad = {
        "no camera 'cam9'": [("cam1", "cam9")],
        "cannot pair with itself": [("cam1", "cam1")],
        "listed twice": [("cam1", "cam2"), ("cam1", "cam2")],
        "the list is empty": [],
        "names two cameras": [("cam1", "cam2", "cam3")],
    }
    for message, pairs in bad.items():
        with pytest.raises(ConfigError, match=message):
            adjacent_pairs(rig, pairs)  # type: ignore[arg-type]
    one = Rig({"solo": rig.cameras["cam1"]}, {"solo": np.eye(4)})
    with pytest.raises(ConfigError, match="two cameras or more"):
        adjacent_pairs(one)
