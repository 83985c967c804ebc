"""CamOdoCal camera YAML (``model_type`` + per-model blocks, written by cv::FileStorage).

Layouts from CamOdoCal's ``readFromYamlFile`` (src/camera_models/*.cc):

- KANNALA_BRANDT (EquidistantCamera): ``projection_parameters {k2 k3 k4 k5 mu mv u0 v0}``;
  k2..k5 are our k1..k4 and mu, mv, u0, v0 our fx, fy, cx, cy.
- MEI (CataCamera): ``mirror_parameters {xi}``, ``distortion_parameters {k1 k2 p1 p2}``,
  ``projection_parameters {gamma1 gamma2 u0 v0}``.
- PINHOLE: ``distortion_parameters {k1 k2 p1 p2}``, ``projection_parameters {fx fy cx cy}``.
- SCARAMUZZA (OCAMCamera): ``poly_parameters {p0..p4}``, ``inv_poly_parameters {p0..p19}``,
  ``affine_parameters {ac ad ae cx cy}``. OCAMCamera works in (u, v) = (column, row) order:
  ``[u - cx; v - cy] = [[ac, ad], [ae, 1]] · (x, y)`` and ``spaceToPlane`` evaluates inv_poly at
  ``atan2(z, |xy|)``. With OCamCalib's sign (p0 < 0) z points backwards and inv_poly is already a
  polynomial in ψ = θ − π/2; with p0 > 0 (z forward) we negate z's argument: odd inv_poly
  coefficients change sign. (OCAMCamera's liftProjective returns the un-stretched offsets as the
  ray's x, y; we follow the published model, which uses the stretched ones.)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from calibration.errors import CalibrationFileError
from calibration.formats.content import CalibrationContent, build_model
from calibration.formats.document import Document, Field
from calibration.models import CameraModel

__all__ = ["is_camodocal", "read_camodocal"]

_MODEL_TYPES = ("KANNALA_BRANDT", "MEI", "PINHOLE", "SCARAMUZZA")


def is_camodocal(tree: Any) -> bool:
    return isinstance(tree, Mapping) and "model_type" in tree


def read_camodocal(doc: Document) -> CalibrationContent:
    root = Field(doc.path, doc.tree)
    type_field = root["model_type"]
    model_type = type_field.string()
    width = root["image_width"].image_extent()
    height = root["image_height"].image_extent()
    name_field = root.get("camera_name")
    name = name_field.string() if name_field is not None and isinstance(name_field.value, str) else ""
    model: CameraModel
    if model_type == "KANNALA_BRANDT":
        p = root["projection_parameters"]
        model = build_model(
            p,
            "kannala_brandt",
            width,
            height,
            fx=p["mu"].number(),
            fy=p["mv"].number(),
            cx=p["u0"].number(),
            cy=p["v0"].number(),
            k1=p["k2"].number(),
            k2=p["k3"].number(),
            k3=p["k4"].number(),
            k4=p["k5"].number(),
        )
    elif model_type == "MEI":
        p = root["projection_parameters"]
        dist = _numbers(root["distortion_parameters"], ("k1", "k2", "p1", "p2"))
        model = build_model(
            p,
            "mei",
            width,
            height,
            xi=root["mirror_parameters"]["xi"].number(),
            fx=p["gamma1"].number(),
            fy=p["gamma2"].number(),
            cx=p["u0"].number(),
            cy=p["v0"].number(),
            **dist,
        )
    elif model_type == "PINHOLE":
        p = root["projection_parameters"]
        dist = _numbers(root["distortion_parameters"], ("k1", "k2", "p1", "p2"))
        model = build_model(p, "pinhole", width, height, **_numbers(p, ("fx", "fy", "cx", "cy")), **dist)
    elif model_type == "SCARAMUZZA":
        model = _read_scaramuzza(root, width, height)
    else:
        raise type_field.error(f"unsupported model_type {model_type!r}; supported: {', '.join(_MODEL_TYPES)}")
    key = name or "cam0"
    aliases = {"cam0": key} if key != "cam0" else {}
    return CalibrationContent(doc.path, "camodocal", {key: model}, aliases)


def _numbers(block: Field, names: tuple[str, ...]) -> dict[str, float]:
    return {n: block[n].number() for n in names}


def _indexed(block: Field) -> list[float]:
    """Coefficients p0, p1, ... up to the first missing index; trailing zeros dropped
    (CamOdoCal pads inv_poly to 20 entries)."""
    block.mapping()
    values: list[float] = []
    while block.has(f"p{len(values)}"):
        values.append(block[f"p{len(values)}"].number())
    if not values:
        raise CalibrationFileError(block.path, "missing", f"{block.name}.p0")
    while len(values) > 1 and values[-1] == 0.0:
        values.pop()
    return values


def _read_scaramuzza(root: Field, width: int, height: int) -> CameraModel:
    poly_field = root["poly_parameters"]
    poly = _indexed(poly_field)
    invpol = _indexed(root["inv_poly_parameters"])
    affine = root["affine_parameters"]
    if poly[0] == 0.0:
        raise poly_field.error("p0 must not be zero (it is the ray's z at the distortion centre)")
    if poly[0] < 0.0:
        # OCamCalib's sign convention: z backwards. inv_poly's atan2(z_file, r) is then ψ itself.
        poly = [-a for a in poly]
    else:
        # z forward: atan2(z, r) = −ψ, so inv_poly(−ψ) re-expressed in ψ flips odd terms.
        invpol = [b if i % 2 == 0 else -b for i, b in enumerate(invpol)]
    return build_model(
        affine,
        "scaramuzza",
        width,
        height,
        {"poly": poly_field, "invpol": root["inv_poly_parameters"]},
        poly=poly,
        invpol=invpol,
        cx=affine["cx"].number(),
        cy=affine["cy"].number(),
        c=affine["ac"].number(),
        d=affine["ad"].number(),
        e=affine["ae"].number(),
    )
