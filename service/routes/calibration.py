"""``/calibration``: the rig's fisheye models, the rectified pair in effect and its footprint per camera."""

from __future__ import annotations

import math

from fastapi import APIRouter

from rig.in_effect import PairInEffect
from service.deps import RuntimeDep
from service.runtime import Runtime
from service.schemas import CalibrationModel, CameraCalibrationModel, RectifiedPairModel

__all__ = ["calibration_model", "rectified_pair_model", "router"]

router = APIRouter(tags=["calibration"])


def rectified_pair_model(in_effect: PairInEffect) -> RectifiedPairModel:
    """The rectified pair in effect as ``/calibration`` and ``/config`` show it (its real size)."""
    pair, config = in_effect.pair, in_effect.config
    return RectifiedPairModel(
        **pair.as_json(),
        left=pair.left,
        right=pair.right,
        hfov_deg=config.hfov_deg if pair.projection == "pinhole" else None,
        px_per_deg=math.radians(pair.camera.fx) if pair.projection == "latlon" else None,
        yaw_deg=config.yaw_deg,
        pitch_deg=config.pitch_deg,
        T_rig_vpc={n: T.tolist() for n, T in pair.T_rig_rect.items()},
    )


def calibration_model(runtime: Runtime) -> CalibrationModel:
    pipeline = runtime.pipeline
    in_effect = pipeline.in_effect
    rig = in_effect.geometry.rig
    fractions = {n: info.lut.valid_fraction for n, info in in_effect.geometry.lut_info.items()}
    cams: dict[str, CameraCalibrationModel] = {}
    for name in rig.names:
        doc = rig.cameras[name].to_dict()
        footprint = pipeline.footprint(name).tolist() if name in in_effect.names else []
        cams[name] = CameraCalibrationModel(
            model=doc["model"],
            width=doc["width"],
            height=doc["height"],
            params={k: float(v) for k, v in doc["params"].items()},
            fov_deg=doc.get("fov_deg"),
            T_rig_cam=rig.T_rig_cam[name].tolist(),
            footprint=[(float(u), float(v)) for u, v in footprint],
            valid_fraction=fractions.get(name),
        )
    return CalibrationModel(
        cameras=cams,
        vpc=rectified_pair_model(in_effect),
        baseline_m=in_effect.pair.baseline_m,
        depth_scale_m=runtime.settings.server.depth_scale_m,
        source=None if runtime.calibration_path is None else str(runtime.calibration_path),
    )


@router.get("/calibration", response_model=CalibrationModel, summary="Rig and rectified pair calibration")
def get_calibration(runtime: RuntimeDep) -> CalibrationModel:
    # Made once per calibration in effect (an online correction brings a new one).
    geometry = runtime.pipeline.in_effect.geometry
    return runtime.documents.get("calibration", geometry, lambda: calibration_model(runtime))
