"""The wide (lat-lon) rectified pair: the overlap it spans, its rows, its lookup tables.

References: closed forms of the overlap of two lenses (a lune; the intersection of two spherical
caps), mrcal's LENSMODEL_LATLON ray written out here, each fisheye model's own ``project``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from calibration.geometry import invert_transform, make_transform, rot_y, transform_points
from calibration.models import LatLonModel, create
from calibration.rig import Rig
from rig.errors import ConfigError
from rig.field import overlap, pixel_solid_angles
from rig.lut import build_rectified_lut
from rig.lut_cache import lut_key
from rig.rectified import DEFAULT_PROJECTION, RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.sim import divergent_rig
from tests.calibration.model_cases import model_cases
from tests.helpers.shots import prototype_rig

F64 = NDArray[np.float64]


def _lens(fov_deg: float, size: int = 1000) -> Rig:
    """Two ideal equidistant lenses, whole image circles, 90° apart, 10 cm apart."""
    f = (size / 2.0 - 2.0) / math.radians(fov_deg / 2.0)
    lens = create(
        "equidistant", size, size, fx=f, fy=f, cx=(size - 1) / 2, cy=(size - 1) / 2, fov_deg=fov_deg
    )
    return divergent_rig(lens, lens.replace(), 0.10, 90.0)


def _cap_intersection_sr(radius: float, separation: float) -> float:
    """Solid angle shared by two spherical caps of angular ``radius`` whose centres are
    ``separation`` apart, by Gauss-Bonnet: ``2π − Σ ∫k_g ds − Σ exterior angles``. Each bounding
    arc spans ``2α`` about its cap's centre with geodesic curvature ``cot r`` (∫ = ``2α cos r``);
    α and the exterior angle γ at the two corners are angles of the triangle (centre, centre,
    corner) with sides r, r, separation (spherical law of cosines)."""
    c, s = math.cos(radius), math.sin(radius)
    cd, sd = math.cos(separation), math.sin(separation)
    alpha = math.acos(c * (1.0 - cd) / (s * sd))
    gamma = math.acos((cd - c * c) / (s * s))
    return 2.0 * math.pi - 2.0 * (2.0 * alpha * c) - 2.0 * gamma


def _ray(az: F64, el: F64) -> F64:
    """mrcal's LENSMODEL_LATLON unprojection, written out: (sin az, cos az sin el, cos az cos el)."""
    return np.stack([np.sin(az), np.cos(az) * np.sin(el), np.cos(az) * np.cos(el)], axis=-1)


def test_overlap_of_two_half_spheres_is_a_quarter_lune() -> None:
    rig = _lens(180.0)
    pair = design_rectified_pair(rig, RectifiedPairConfig(projection="latlon"))
    view = overlap(rig, pair.R_rig_rect, "left", "right", 0.25)
    assert view.solid_angle_sr == pytest.approx(math.pi, rel=5e-3)  # a lune of 90°: 2·(π/2)
    az0, az1, el0, el1 = np.degrees(view.bounds())
    assert az0 == pytest.approx(-45.0, abs=0.6) and az1 == pytest.approx(45.0, abs=0.6)
    assert el0 == pytest.approx(-90.0, abs=0.6) and el1 == pytest.approx(90.0, abs=0.6)


def test_overlap_of_two_190_degree_lenses_is_the_cap_intersection() -> None:
    rig = _lens(190.0)
    pair = design_rectified_pair(rig, RectifiedPairConfig(projection="latlon"))
    got = overlap(rig, pair.R_rig_rect, "left", "right", 0.2).solid_angle_sr
    assert got == pytest.approx(_cap_intersection_sr(math.radians(95.0), math.radians(90.0)), rel=3e-3)
    assert got > math.pi  # wider than the lune: the 5° past 90° on each lens


def test_a_rig_that_shares_no_direction_is_one_error() -> None:
    pin = create("pinhole", 200, 200, fx=100.0, fy=100.0, cx=99.5, cy=99.5)
    apart = Rig(  # 90° views whose axes are 160° apart
        {"left": pin, "right": pin.replace()},
        {
            "left": make_transform(rot_y(math.radians(-80)), [-0.05, 0, 0]),
            "right": make_transform(rot_y(math.radians(80)), [0.05, 0, 0]),
        },
    )
    with pytest.raises(ConfigError, match="no stereo overlap"):
        design_rectified_pair(apart, RectifiedPairConfig(projection="latlon"))


def _pair(rig: Rig, band: int = 64, **kw: float) -> RectifiedPair:
    return design_rectified_pair(rig, RectifiedPairConfig(projection="latlon", **kw), blind_band_px=band)  # type: ignore[arg-type]


def test_default_field_holds_the_whole_overlap_right_of_the_blind_band() -> None:
    rig = prototype_rig(0.5)
    pair = _pair(rig, band=64, px_per_deg=3.0)
    cam = pair.camera
    assert isinstance(cam, LatLonModel) and pair.projection == "latlon"
    assert cam.fx == pytest.approx(math.degrees(3.0)) and cam.fy == cam.fx
    # Every direction both lenses see (a fine grid, independent of the design's own) lands in the
    # image, right of the 64 columns the matcher cannot match.
    view = overlap(rig, pair.R_rig_rect, "left", "right", 0.2)
    el, az = np.meshgrid(view.el, view.az, indexing="ij")
    pix, ok = cam.project(_ray(az[view.inside], el[view.inside]))
    assert ok.all()
    assert pix[:, 0].min() >= 64 - 0.5
    # ... and the field is not much wider: within 2 px (one grid step) of the overlap's edges.
    assert pix[:, 0].max() > cam.width - 1 - 3.0
    assert pix[:, 1].min() < 3.0 and pix[:, 1].max() > cam.height - 1 - 3.0


def test_rows_are_epipolar_planes_on_a_non_ideal_mount() -> None:
    base = prototype_rig(0.5)
    rig = divergent_rig(base.cameras["left"], base.cameras["right"], 0.072, 87.0, 2.0, 1.0)
    pair = _pair(rig, band=32, px_per_deg=4.0)
    rng = np.random.default_rng(0)
    dirs = _ray(rng.uniform(-0.8, 0.8, 500), rng.uniform(-1.5, 1.5, 500))
    pts_rig = transform_points(pair.T_rig_rect["left"], dirs * rng.uniform(0.3, 20.0, (500, 1)))
    pl, okl = pair.camera.project(transform_points(invert_transform(pair.T_rig_rect["left"]), pts_rig))
    pr, okr = pair.camera.project(transform_points(invert_transform(pair.T_rig_rect["right"]), pts_rig))
    ok = okl & okr
    assert ok.sum() > 400
    assert np.abs(pl[ok, 1] - pr[ok, 1]).max() < 1e-9, "a point's row is the same in both views"
    assert (pl[ok, 0] > pr[ok, 0]).all(), "disparity is positive"


def test_an_explicit_field_wider_than_the_overlap_is_clipped_with_a_note() -> None:
    rig = prototype_rig(0.5)
    full = _pair(rig, band=0, px_per_deg=2.0)
    assert full.field_note is None
    wide = _pair(rig, band=0, px_per_deg=2.0, az_span_deg=170.0, el_span_deg=300.0)
    assert wide.field_note is not None and "clipped" in wide.field_note
    frac = float(wide.field_note.split("(")[1].split("%")[0]) / 100.0
    # The requested box is ~170° x 300°; the overlap covers ~3.67 sr of its solid angle.
    box_sr = 2 * math.sin(math.radians(85.0)) * math.radians(300.0)
    assert frac == pytest.approx(3.67 / box_sr, abs=0.03)
    assert (wide.camera.width, wide.camera.height) == (full.camera.width, full.camera.height)
    inside = _pair(rig, band=0, px_per_deg=2.0, az_span_deg=40.0, el_span_deg=30.0, pitch_deg=20.0)
    assert inside.field_note is None and inside.camera.width == 80 and inside.camera.height == 60
    # Pitch up (+) looks at negative elevations (y points down): the centre row looks 20° up.
    centre = inside.camera.unproject([[39.5, 29.5]])[0][0]
    assert math.degrees(math.atan2(centre[1], centre[2])) == pytest.approx(-20.0, abs=1e-9)


def test_config_keeps_each_projection_to_its_own_settings() -> None:
    with pytest.raises(ValueError, match="width does not apply to the latlon"):
        RectifiedPairConfig(projection="latlon", width=800)
    with pytest.raises(ValueError, match="px_per_deg does not apply to the pinhole"):
        RectifiedPairConfig(projection="pinhole", px_per_deg=4.0)
    with pytest.raises(ValueError, match="px_per_deg does not apply to the pinhole"):
        RectifiedPairConfig(width=800, px_per_deg=4.0)  # the pinhole's own field selects the pinhole
    # The default is the lat-lon pair; a configuration with the pinhole's fields keeps meaning it.
    assert RectifiedPairConfig().projection == DEFAULT_PROJECTION == "latlon"
    assert RectifiedPairConfig(width=320, height=240).projection == "pinhole"
    assert RectifiedPairConfig(hfov_deg=100).projection == "pinhole"
    with pytest.raises(ValueError, match="yaw_deg centre an explicit lat-lon field"):
        RectifiedPairConfig(yaw_deg=10.0)
    with pytest.raises(ValueError, match="yaw_deg and pitch_deg centre an explicit lat-lon field"):
        RectifiedPairConfig(yaw_deg=10.0, pitch_deg=-5.0)
    # A lat-lon configuration has no pinhole size; a pinhole one gets its defaults.
    assert RectifiedPairConfig().width is None and RectifiedPairConfig(projection="pinhole").width == 640
    assert RectifiedPairConfig(yaw_deg=10.0, az_span_deg=40.0).yaw_deg == 10.0
    with pytest.raises(ValueError, match="projection"):
        RectifiedPairConfig(projection="fisheye")  # type: ignore[arg-type]
    # A dumped config validates again (defaults of the other projection are not "set").
    cfg = RectifiedPairConfig(projection="latlon", px_per_deg=4.0)
    assert RectifiedPairConfig(**cfg.model_dump()) == cfg


@pytest.mark.parametrize("case", model_cases(), ids=lambda c: c.id)
def test_latlon_lut_of_every_model_equals_its_projection_of_each_ray(case) -> None:  # type: ignore[no-untyped-def]
    """The table's fast path (outer products of one row and one column) against mrcal's ray
    formula per pixel and the fisheye model's own ``project``; invalid exactly where the lens
    cannot see."""
    model = case.model
    yaw = min(math.degrees(model.max_theta) - 20.0, 80.0) if case.wide else 10.0
    R = rot_y(math.radians(yaw))  # rectified -> camera: the view crosses a wide lens's limit
    f = math.degrees(1.0) * 1.5
    cam = LatLonModel(150, 240, fx=f, fy=f, cx=74.5, cy=119.5)  # 100° x 160°
    lut = build_rectified_lut(model, R, cam)
    el, az = np.meshgrid(cam.elevations(), cam.azimuths(), indexing="ij")
    pix, ok = model.project(_ray(az, el).reshape(-1, 3) @ R.T)
    assert np.array_equal(lut.valid.ravel(), ok)
    assert lut.valid_fraction > 0.05
    got = np.stack([lut.map_x.ravel(), lut.map_y.ravel()], 1)[ok]
    assert np.abs(got - pix[ok]).max() < 1e-3
    if case.wide and model.max_theta > math.radians(91):
        theta = np.arccos(np.clip((_ray(az, el) @ R.T)[..., 2], -1, 1))
        assert lut.valid[theta > math.radians(90.5)].any(), "rays past 90° are kept up to the lens's limit"
        assert not lut.valid[theta > model.max_theta * (1 + 1e-9)].any()


def test_latlon_and_pinhole_tables_of_the_same_numbers_have_different_keys() -> None:
    lens = prototype_rig(0.25).cameras["left"]
    a = create("pinhole", 100, 80, fx=60.0, fy=60.0, cx=49.5, cy=39.5)
    b = LatLonModel(100, 80, fx=60.0, fy=60.0, cx=49.5, cy=39.5)
    assert lut_key(lens, np.eye(3), a) != lut_key(lens, np.eye(3), b)


@pytest.mark.parametrize(
    "camera",
    [
        LatLonModel(90, 120, fx=40.0, fy=45.0, cx=44.5, cy=50.0),
        create("pinhole", 80, 60, fx=40.0, fy=41.0, cx=39.5, cy=29.5),
    ],
    ids=["latlon", "pinhole"],
)
def test_pixel_solid_angles_match_the_closed_forms_and_add_up(camera) -> None:  # type: ignore[no-untyped-def]
    got = pixel_solid_angles(camera)
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    if isinstance(camera, LatLonModel):
        expected = np.cos((u - camera.cx) / camera.fx) / (camera.fx * camera.fy)
        az = (np.array([-0.5, camera.width - 0.5]) - camera.cx) / camera.fx
        el = (np.array([-0.5, camera.height - 0.5]) - camera.cy) / camera.fy
        total = (math.sin(az[1]) - math.sin(az[0])) * (el[1] - el[0])  # ∫∫ cos(az) daz del
    else:
        expected = (1 + ((u - camera.cx) / camera.fx) ** 2 + ((v - camera.cy) / camera.fy) ** 2) ** -1.5
        expected /= camera.fx * camera.fy
        # The pyramid over a rectangle centred on the axis, half-sides ta, tb at z = 1:
        # 4·atan(ta·tb / sqrt(1 + ta² + tb²)).
        ta, tb = camera.width / 2 / camera.fx, camera.height / 2 / camera.fy
        total = 4 * math.atan(ta * tb / math.sqrt(1 + ta**2 + tb**2))
    assert np.allclose(got, expected, rtol=2e-4)
    assert got.sum() == pytest.approx(total, rel=1e-4)


def test_pixel_solid_angles_of_a_latlon_view_are_its_rays_differences() -> None:
    """The lat-lon closed form used for speed is the generic finite differences of the rays."""
    camera = LatLonModel(180, 150, fx=60.0, fy=50.0, cx=89.5, cy=70.0)  # to ±85.9°
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)

    def rays(du: float, dv: float) -> np.ndarray:
        pix = np.stack([(u + du).ravel(), (v + dv).ravel()], axis=1)
        return camera.unproject(pix, in_image=False)[0].reshape(camera.height, camera.width, 3)

    along_u, along_v = rays(0.5, 0) - rays(-0.5, 0), rays(0, 0.5) - rays(0, -0.5)
    expected = np.linalg.norm(np.cross(along_u, along_v), axis=2)
    assert np.allclose(pixel_solid_angles(camera), expected, rtol=1e-9, atol=0)
    beyond = LatLonModel(200, 150, fx=60.0, fy=50.0, cx=99.5, cy=70.0)  # to ±95.5°: past the poles
    outside = np.abs(beyond.azimuths()) > np.pi / 2
    assert outside.sum() == 12 and not pixel_solid_angles(beyond)[:, outside].any()
