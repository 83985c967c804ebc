"""`rig evaluate`: the paper's analysis (its §IV) reproduced on the virtual environment (docs/evaluation.md).

1. Calibration quality (Table I): chessboards rendered through the preset's true lens, corners
   detected, every model calibrated — :mod:`rig.evaluate.calibration_quality`.
2. Distortion removal (Fig. 6): each model's VPC image against the Reference camera's —
   :mod:`rig.evaluate.distortion`.
3. Depth quality (Fig. 7, 12): a textured plane at k baselines through every model's depth
   pipeline, the Reference pair and the theory — :mod:`rig.evaluate.depth_quality`.
4. Matcher choice: SGBM, SGBM_3WAY, BM and ours — :mod:`rig.evaluate.matchers`.

:func:`make_config` → :func:`run_evaluation` → :func:`write_outputs`.
"""

from rig.evaluate.config import DEFAULT_MODELS, EvalConfig, make_config
from rig.evaluate.report import OUTPUT_FILES, results_document, write_outputs
from rig.evaluate.runner import EvaluationRun, ProgressSink, run_evaluation

__all__ = [
    "DEFAULT_MODELS",
    "OUTPUT_FILES",
    "EvalConfig",
    "EvaluationRun",
    "ProgressSink",
    "make_config",
    "results_document",
    "run_evaluation",
    "write_outputs",
]
