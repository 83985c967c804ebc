"""``/calibration``: the rig's fisheye models, the VPC pair and the VPC footprint per camera."""

from __future__ import annotations

from fastapi import APIRouter

from service.deps import RuntimeDep
from service.runtime import Runtime
from service.schemas import CalibrationModel, CameraCalibrationModel, RectifiedPairModel

__all__ = ["calibration_model", "router"]

router = APIRouter(tags=["calibration"])


def calibration_model(runtime: Runtime) -> CalibrationModel:
    pipeline = runtime.pipeline
    pair = pipeline.pair
    vpc = pipeline.pair_config
    cams: dict[str, CameraCalibrationModel] = {}
    for name in runtime.rig.names:
        model = runtime.rig.cameras[name]
        doc = model.to_dict()
        footprint = pipeline.footprint(name).tolist() if name in pipeline.names else []
        cams[name] = CameraCalibrationModel(
            model=doc["model"],
            width=doc["width"],
            height=doc["height"],
            params={k: float(v) for k, v in doc["params"].items()},
            fov_deg=doc.get("fov_deg"),
            T_rig_cam=runtime.rig.T_rig_cam[name].tolist(),
            footprint=[(float(u), float(v)) for u, v in footprint],
            valid_fraction=pipeline.valid_fraction.get(name),
        )
    return CalibrationModel(
        cameras=cams,
        vpc=RectifiedPairModel(
            **pair.as_json(),
            hfov_deg=vpc.hfov_deg if pair.projection == "pinhole" else None,
            px_per_deg=vpc.resolution_px_per_deg if pair.projection == "latlon" else None,
            yaw_deg=vpc.yaw_deg,
            pitch_deg=vpc.pitch_deg,
            T_rig_vpc={n: T.tolist() for n, T in pair.T_rig_rect.items()},
        ),
        baseline_m=pair.baseline_m,
        depth_scale_m=runtime.settings.server.depth_scale_m,
        source=None if runtime.calibration_path is None else str(runtime.calibration_path),
    )


@router.get("/calibration", response_model=CalibrationModel, summary="Rig and VPC calibration")
def get_calibration(runtime: RuntimeDep) -> CalibrationModel:
    # Computed once, and again after an online rectification correction (Runtime drops it).
    cached: CalibrationModel | None = runtime.calibration_doc
    if cached is None:
        cached = calibration_model(runtime)
        runtime.calibration_doc = cached
    return cached
