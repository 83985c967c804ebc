"""Camera models: one interface (``project``/``unproject`` with validity masks) for all.

``create(name, width, height, **params)`` builds one by name; :data:`MODELS` lists them.
"""

from calibration.models.base import MODELS, CameraModel, create, register
from calibration.models.equidistant import EquidistantModel
from calibration.models.kannala_brandt import KannalaBrandtModel
from calibration.models.pinhole import PinholeModel

__all__ = [
    "MODELS",
    "CameraModel",
    "EquidistantModel",
    "KannalaBrandtModel",
    "PinholeModel",
    "create",
    "register",
]
