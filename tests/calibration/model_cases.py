"""One realistic instance of every camera model, used by the parametrized model suite.

Add a model here and every generic test runs on it. ``wide`` marks lenses that see past 90°.

Published parameter sets: basalt-headers ``getTestProjections()`` (VladyslavUsenko/basalt-headers,
include/basalt/camera/{kannala_brandt_camera4,double_sphere_camera,extended_camera}.hpp; the EUCM
ones are the EuRoC and TUM VI calibrations, image sizes from ``getTestResolutions()``; KB4 and DS
give no size, 1024x1024 fits their principal points) and CamOdoCal's CataCamera test
(hengli/camodocal, src/camera_models/CataCamera_test.cc, 1280x800). The others are synthetic but
shaped like real lenses (the Scaramuzza polynomials are least-squares fits of an equidistant
lens in OCamCalib's a0, 0, a2, a3, a4 form, rounded like a calib_results.txt).
"""

from __future__ import annotations

from dataclasses import dataclass

from calibration.models import CameraModel, create


@dataclass(frozen=True)
class ModelCase:
    id: str
    model: CameraModel
    wide: bool


def model_cases() -> list[ModelCase]:
    return [
        ModelCase(
            "kannala_brandt-190",
            create(
                "kannala_brandt",
                1280,
                960,
                fx=285.0,
                fy=284.2,
                cx=652.3,
                cy=471.8,
                k1=0.0241,
                k2=-0.0153,
                k3=0.0047,
                k4=-0.00061,
                fov_deg=190.0,
            ),
            True,
        ),
        ModelCase(
            "kannala_brandt-basalt",
            create(
                "kannala_brandt",
                1024,
                1024,
                fx=379.045,
                fy=379.008,
                cx=505.512,
                cy=509.969,
                k1=0.00693023,
                k2=-0.0013828,
                k3=-0.000272596,
                k4=-0.000452646,
            ),
            True,
        ),
        ModelCase(
            "equidistant-180",
            create("equidistant", 800, 800, fx=254.6, fy=254.6, cx=399.5, cy=399.5, fov_deg=180.0),
            False,
        ),
        ModelCase(
            "equidistant-200",
            create("equidistant", 900, 700, fx=230.0, fy=231.0, cx=450.2, cy=349.1, fov_deg=200.0),
            True,
        ),
        ModelCase(
            "pinhole",
            create("pinhole", 640, 480, fx=320.0, fy=321.0, cx=319.5, cy=239.5),
            False,
        ),
        *_omnidirectional_cases(),
        ModelCase(
            "pinhole-radtan",
            create(
                "pinhole",
                752,
                480,
                fx=458.654,
                fy=457.296,
                cx=367.215,
                cy=248.375,
                k1=-0.28340811,
                k2=0.07395907,
                p1=0.00019359,
                p2=1.76187114e-05,
            ),
            False,
        ),
    ]


# A calib_results.txt-style invpol (6 decimals) for the 190° Scaramuzza lens below.
INVPOL_190 = [471.017496, 301.26937, 15.602681, 34.508414, 25.767332, 4.450325, 2.367443, 6.491317]
INVPOL_190 += [3.691145, 0.619224]


def _omnidirectional_cases() -> list[ModelCase]:
    """Mei, Double Sphere, EUCM and Scaramuzza cases."""
    wide_poly = [3.003179e02, 0.0, -1.214037e-03, 7.059883e-07, -2.128193e-09]
    wide_scaramuzza = dict(poly=wide_poly, cx=643.2, cy=475.9, c=1.0003, d=-0.0002, e=0.0004, fov_deg=190.0)
    return [
        ModelCase(
            "mei-camodocal",
            create(
                "mei",
                1280,
                800,
                xi=0.894975,
                k1=-0.344504,
                k2=0.0984552,
                p1=-0.00403995,
                p2=0.00610364,
                fx=758.355,
                fy=757.615,
                cx=646.72,
                cy=395.001,
            ),
            True,
        ),
        ModelCase(
            # ξ > 1: only the cap beyond the tangent circle Zs = -1/ξ is one-to-one; with skew.
            "mei-xi1.6-skew",
            create(
                "mei",
                1280,
                960,
                xi=1.6,
                k1=-0.08,
                k2=0.01,
                p1=1e-4,
                p2=-2e-4,
                fx=740.2,
                fy=739.1,
                cx=641.3,
                cy=478.6,
                s=0.35,
            ),
            True,
        ),
        ModelCase(
            "double_sphere-basalt",
            create(
                "double_sphere",
                1024,
                1024,
                fx=402.5,
                fy=400.0,
                cx=505.0,
                cy=509.0,
                xi=-0.075347,
                alpha=0.743925,
            ),
            True,
        ),
        ModelCase(
            # α <= 0.5: every pixel unprojects; the projection limit alone bounds the field.
            "double_sphere-alpha0.45",
            create("double_sphere", 1024, 768, fx=270.3, fy=269.8, cx=515.1, cy=381.7, xi=0.4, alpha=0.45),
            True,
        ),
        ModelCase(
            "eucm-basalt-euroc",
            create(
                "eucm",
                752,
                480,
                fx=460.76484651566468,
                fy=459.4051018049483,
                cx=365.8937161309615,
                cy=249.33499869752445,
                alpha=0.5903365915227143,
                beta=1.127468196965374,
            ),
            False,
        ),
        ModelCase(
            "eucm-basalt-tumvi",
            create(
                "eucm",
                512,
                512,
                fx=191.14799816648748,
                fy=191.13150946585135,
                cx=254.95857715233118,
                cy=256.8815466235898,
                alpha=0.6291060871161842,
                beta=1.0418067403139693,
            ),
            True,
        ),
        ModelCase(
            "eucm-alpha0.42",
            create("eucm", 1024, 768, fx=180.4, fy=180.1, cx=509.6, cy=386.2, alpha=0.42, beta=1.3),
            True,
        ),
        ModelCase("scaramuzza-190-fitted", create("scaramuzza", 1280, 960, **wide_scaramuzza), True),
        ModelCase(
            # The same lens with an invpol given as a calib_results.txt would (6 decimals).
            "scaramuzza-190-invpol",
            create(
                "scaramuzza",
                1280,
                960,
                **wide_scaramuzza,
                invpol=INVPOL_190,
            ),
            True,
        ),
        ModelCase(
            "scaramuzza-640",
            create(
                "scaramuzza",
                640,
                480,
                poly=[2.600154e02, 0.0, -1.297677e-03, 1.922950e-07, -1.913566e-09],
                cx=322.4,
                cy=237.1,
                c=0.9996,
                d=0.0011,
                e=-0.0007,
            ),
            False,
        ),
    ]
