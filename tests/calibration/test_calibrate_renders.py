"""Every model on rendered chessboards of its own true lens (the virtual environment), end to end:
render → ``findChessboardCornersSB`` → calibration from no guess.

The renders carry exact truth (lens and board poses), which gives two independent references:
the true lens itself, and the reprojection error of the true lens and poses on the same
detections (a feasible point, so the optimum can only be lower).
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration.calibrate import calibrate_camera
from calibration.targets import board_object_points, detect_chessboard
from tests.calibration.calibration_renders import (
    BOARD,
    circle_views,
    lens_difference,
    pinhole_views,
    render_board,
    true_corners,
    true_lenses,
)

LENSES = true_lenses(480)
X = board_object_points(*BOARD, 0.05)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(LENSES))
def test_each_model_recovers_its_rendered_lens(name: str) -> None:
    lens = LENSES[name]
    poses = pinhole_views() if name == "pinhole" else circle_views()
    detections, truth_err, angles = [], [], []
    for T in poses:
        corners = detect_chessboard(render_board(lens, T), BOARD)
        detections.append(corners)
        if corners is not None:
            true_px, angle = true_corners(lens, T)
            truth_err.append(np.linalg.norm(corners - true_px, axis=1))
            angles.append(angle)
    assert sum(d is not None for d in detections) >= len(poses) - 1
    result = calibrate_camera(name, [X] * len(poses), detections, (480, 480), fov_deg=lens.fov_deg)
    truth_rms = float(np.sqrt(np.mean(np.concatenate(truth_err) ** 2)))

    assert result.rms <= 0.1
    assert result.rms <= truth_rms  # the true lens and poses are a feasible point
    if name != "pinhole":
        used_angles = np.concatenate(
            [a for a, d in zip(angles, [d for d in detections if d is not None], strict=True)]
        )
        assert (used_angles > 90.0).sum() >= 10 and result.max_angle_deg > 90.0
        assert len(result.views) == sum(d is not None for d in detections)  # nothing past 90° dropped
    # The lens over the observed field: limited by the detector (~0.1 px per corner against
    # the truth here), not by the calibration (exact corners give 1e-13 px: test_calibrate).
    lens_rms, lens_max = lens_difference(lens, result.camera, result.max_angle_deg)
    assert lens_rms < 0.75 and lens_max < 1.5, (lens_rms, lens_max)
