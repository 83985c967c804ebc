"""One realistic instance of every camera model, used by the parametrized model suite.

Add a model here and every generic test runs on it. ``wide`` marks lenses that see past 90°.
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
