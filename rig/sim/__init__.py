"""The virtual environment: textured scenes, a ray-cast renderer for any camera model, simulated
rigs (presets) and recordings with exact ground truth (docs/evaluation.md).

World frame = rig frame (docs/design.md, "Conventions": x right, y down, z forward), metres.
"""

from rig.sim.lens_effects import HONEST_LENS, IDEAL_LENS, CameraExposure, LensEffects
from rig.sim.mount import divergent_rig
from rig.sim.presets import PRESETS, Preset, get_preset, scale_camera
from rig.sim.render import Geometry, Render, render, render_geometry, render_range, vignetting_factor
from rig.sim.scene import (
    Scene,
    TexturedRect,
    chessboard_corners,
    chessboard_scene,
    plane_scene,
    rect_from_axes,
    room_scene,
)
from rig.sim.simulate import SCENES, room_path, simulate_recording
from rig.sim.textures import TEXTURES, CheckerTexture, ImageTexture, Texture, make_texture

__all__ = [
    "HONEST_LENS",
    "IDEAL_LENS",
    "PRESETS",
    "SCENES",
    "TEXTURES",
    "CameraExposure",
    "CheckerTexture",
    "Geometry",
    "ImageTexture",
    "LensEffects",
    "Preset",
    "Render",
    "Scene",
    "Texture",
    "TexturedRect",
    "chessboard_corners",
    "chessboard_scene",
    "divergent_rig",
    "get_preset",
    "make_texture",
    "plane_scene",
    "rect_from_axes",
    "render",
    "render_geometry",
    "render_range",
    "room_path",
    "room_scene",
    "scale_camera",
    "simulate_recording",
    "vignetting_factor",
]
