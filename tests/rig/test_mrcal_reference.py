"""The lat-lon pair against mrcal itself (its own Python, in a subprocess): the projection
(``LENSMODEL_LATLON``, and the panorama's ``LENSMODEL_LONLAT``), the rectified frame and
intrinsics of ``mrcal.rectified_system`` and the ranges of ``mrcal.stereo_range``.

mrcal is not on PyPI for this Python; Debian ships it (``apt-get install python3-mrcal``) for the
system interpreter. ``RIG_MRCAL_PYTHON`` names an interpreter that imports it (default
``/usr/bin/python3``); where none does these tests skip, saying so (they fail instead in CI, which
installs it). The same conventions are tested without mrcal in tests/calibration/test_latlon.py
and tests/rig/test_range.py.
"""

from __future__ import annotations

import math
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from calibration.geometry import invert_transform, make_transform, rot_x, rot_y
from calibration.models import EquirectModel, LatLonModel, create
from calibration.rig import Rig
from rig.depth import latlon_range
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from tests.helpers.inputs import missing_input

_PYTHON = os.environ.get("RIG_MRCAL_PYTHON", "/usr/bin/python3")


def _mrcal_python() -> str:
    try:
        probe = subprocess.run([_PYTHON, "-c", "import mrcal"], capture_output=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as err:
        missing_input("mrcal", f"no interpreter {_PYTHON} ({err}); set RIG_MRCAL_PYTHON")
    if probe.returncode != 0:
        missing_input(
            "mrcal", f"{_PYTHON} cannot import it (apt-get install python3-mrcal, or set RIG_MRCAL_PYTHON)"
        )
    return _PYTHON


def _run(tmp_path: Path, script: str, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    src = tmp_path / "in.npz"
    dst = tmp_path / "out.npz"
    np.savez(src, **inputs)
    head = f"import numpy as np, mrcal\nI = dict(np.load({str(src)!r}))\nO = {{}}\n"
    code = f"{head}{script}\nnp.savez({str(dst)!r}, **O)\n"
    res = subprocess.run([_mrcal_python(), "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    return dict(np.load(dst))


def test_projection_is_mrcal_latlon(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(3000, 3)) * rng.uniform(0.1, 30.0, (3000, 1))
    m = LatLonModel(3000, 3000, fx=600.0, fy=550.0, cx=1510.2, cy=1480.7)
    out = _run(
        tmp_path,
        "O['q'] = mrcal.project(I['p'], 'LENSMODEL_LATLON', I['k'])",
        {"p": pts, "k": np.array([m.fx, m.fy, m.cx, m.cy])},
    )
    ours, ok = m.project(pts, in_image=False)
    assert ok.all()
    assert np.abs(ours - out["q"]).max() < 1e-8


def test_panorama_projection_is_mrcal_lonlat(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(3000, 3)) * rng.uniform(0.1, 30.0, (3000, 1))
    m = EquirectModel.whole_sphere(3.0)
    out = _run(
        tmp_path,
        "O['q'] = mrcal.project(I['p'], 'LENSMODEL_LONLAT', I['k'])",
        {"p": pts, "k": np.array([m.fx, m.fy, m.cx, m.cy])},
    )
    ours, ok = m.project(pts, in_image=False)
    assert ok.all()
    assert np.abs(ours - out["q"]).max() < 1e-8


def _tilted_rig() -> Rig:
    """Two wide pinholes (mrcal models them exactly), yawed apart, the right one pitched and set
    back: the rectified frame is not the rig frame."""
    pin = create("pinhole", 800, 600, fx=250.0, fy=250.0, cx=399.5, cy=299.5)
    return Rig(
        {"left": pin, "right": pin.replace()},
        {
            "left": make_transform(rot_y(math.radians(-25.0)), [-0.06, 0.0, 0.0]),
            "right": make_transform(
                rot_y(math.radians(20.0)) @ rot_x(math.radians(4.0)), [0.06, 0.01, -0.02]
            ),
        },
    )


def test_rectified_system_and_stereo_range_are_mrcals(tmp_path: Path) -> None:
    rig = _tilted_rig()
    ppd, az_span, el_span = 4.0, 44.0, 50.0
    pair = design_rectified_pair(
        rig,
        RectifiedPairConfig(projection="latlon", px_per_deg=ppd, az_span_deg=az_span, el_span_deg=el_span),
    )
    assert pair.field_note is None
    cam = pair.camera
    assert isinstance(cam, LatLonModel)
    rng = np.random.default_rng(1)
    disparity = rng.uniform(0.5, 60.0, (cam.height, cam.width)).astype(np.float32)
    # mrcal's Rt "from ref" (4, 3: R then t) maps the reference (our rig) frame into the camera's.
    Rt = np.stack(
        [
            np.vstack([T[:3, :3], T[:3, 3]])
            for T in (invert_transform(rig.T_rig_cam[n]) for n in ("left", "right"))
        ]
    )
    script = """
models = [mrcal.cameramodel(intrinsics=('LENSMODEL_PINHOLE', I['k']), imagersize=(800, 600),
                            extrinsics_Rt_fromref=Rt) for Rt in I['Rt']]
rect, meta = mrcal.rectified_system(models, az_fov_deg=float(I['az']), el_fov_deg=float(I['el']),
                                    az0_deg=0.0, el0_deg=0.0, pixels_per_deg_az=float(I['ppd']),
                                    pixels_per_deg_el=float(I['ppd']), rectification_model='LENSMODEL_LATLON',
                                    return_metadata=True)
O['R_rect_ref'] = rect[0].extrinsics_Rt_fromref()[:3]
O['t_rect_ref'] = rect[0].extrinsics_Rt_fromref()[3]
O['size'] = np.array(rect[0].imagersize())
O['k_rect'] = rect[0].intrinsics()[1]
O['baseline'] = np.array(meta['baseline'])
O['range'] = mrcal.stereo_range(I['d'], rect)
"""
    out = _run(
        tmp_path,
        script,
        {
            "k": np.array([250.0, 250.0, 399.5, 299.5]),
            "Rt": Rt,
            "az": np.array(az_span),
            "el": np.array(el_span),
            "ppd": np.array(ppd),
            "d": disparity,
        },
    )
    assert np.abs(out["R_rect_ref"].T - pair.R_rig_rect).max() < 1e-12
    assert np.allclose(-out["R_rect_ref"].T @ out["t_rect_ref"], pair.T_rig_rect["left"][:3, 3], atol=1e-12)
    assert tuple(out["size"]) == (cam.width, cam.height)
    assert np.allclose(out["k_rect"], [cam.fx, cam.fy, cam.cx, cam.cy], rtol=0, atol=1e-9)
    assert float(out["baseline"]) == pytest.approx(pair.baseline_m, rel=1e-12)
    ours = latlon_range(disparity, cam, pair.baseline_m)
    ok = np.isfinite(ours)
    assert ok.mean() > 0.99
    assert np.array_equal(ok, out["range"] > 0)
    assert np.abs(ours[ok] / out["range"][ok] - 1.0).max() < 1e-5  # float32 against float64
