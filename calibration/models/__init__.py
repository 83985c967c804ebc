"""Camera models: one interface (``project``/``unproject`` with validity masks) for all.

``create(name, width, height, **params)`` builds one by name; :data:`MODELS` lists them.
:class:`LatLonModel` (the wide rectified view) and :class:`EquirectModel` (a panorama) have the same
surface but are no lenses: not in MODELS.
"""

from calibration.models.base import MODELS, CameraModel, create, register
from calibration.models.double_sphere import DoubleSphereModel
from calibration.models.equidistant import EquidistantModel
from calibration.models.equirect import EquirectModel
from calibration.models.eucm import EucmModel
from calibration.models.kannala_brandt import KannalaBrandtModel
from calibration.models.latlon import LatLonModel
from calibration.models.mei import MeiModel
from calibration.models.pinhole import PinholeModel
from calibration.models.scaramuzza import ScaramuzzaModel

__all__ = [
    "MODELS",
    "CameraModel",
    "DoubleSphereModel",
    "EquidistantModel",
    "EquirectModel",
    "EucmModel",
    "KannalaBrandtModel",
    "LatLonModel",
    "MeiModel",
    "PinholeModel",
    "ScaramuzzaModel",
    "create",
    "register",
]
