"""The paper's claims checked against one run's numbers, for the report's "agreement" section.

Each claim compares numbers of this run only; a difference smaller than :data:`TIE` (relative)
counts as no measurable difference, so a claim that one model is worse than another is not
"confirmed" by noise.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rig.evaluate.depth_quality import REFERENCE, THEORY, TRUE_LENS, CurvePoint
from rig.evaluate.metrics import loglog_slope

__all__ = ["TIE", "Claim", "check_claims", "mean_ratio"]

#: Relative difference below which two numbers count as equal.
TIE = 0.05
#: "Almost identical to the Reference": mean RMS ratio at most this.
CLOSE = 1.2
KB, MEI, SCARAMUZZA, EQUIDISTANT = "kannala_brandt", "mei", "scaramuzza", "equidistant"


@dataclass(frozen=True)
class Claim:
    """``verdict`` is "agrees", "differs" or "not measured"."""

    topic: str
    paper: str
    ours: str
    verdict: str


def mean_ratio(curve: Sequence[CurvePoint], reference: Sequence[CurvePoint]) -> float:
    """Mean over the shared distances of RMS(curve) / RMS(reference)."""
    ref = {p.k: p.rms_m for p in reference}
    r = [p.rms_m / ref[p.k] for p in curve if p.k in ref and ref[p.k] > 0 and math.isfinite(p.rms_m)]
    return float(np.mean(r)) if r else math.nan


def _worse(a: float, b: float) -> str:
    """'agrees' when a is worse (larger) than b beyond the tie margin."""
    if not (math.isfinite(a) and math.isfinite(b)):
        return "not measured"
    return "agrees" if a > b * (1.0 + TIE) else "differs"


def _fmt(values: Mapping[str, float], unit: str = "") -> str:
    text = ", ".join(f"{k} {v:.3g}" for k, v in values.items() if math.isfinite(v))
    return f"{text} ({unit})" if unit and text else text


def check_claims(
    calibration_rms: Mapping[str, float],
    image_difference: Mapping[str, float],
    curves: Mapping[str, Sequence[CurvePoint]],
) -> list[Claim]:
    """The paper's claims (§IV-B) against ``calibration_rms`` (model -> px), ``image_difference``
    (name -> grey levels) and the depth ``curves`` of one run."""
    out: list[Claim] = []
    # Table I: KB 0.099 and Mei 0.102 differ by 3 %, under TIE: the claim is KB ≲ Mei < Scaramuzza.
    three = {m: calibration_rms[m] for m in (KB, MEI, SCARAMUZZA) if m in calibration_rms}
    if len(three) == 3 and all(math.isfinite(v) for v in three.values()):
        scaramuzza_worst = _worse(three[SCARAMUZZA], max(three[KB], three[MEI])) == "agrees"
        kb_not_worse = three[KB] <= three[MEI] * (1.0 + TIE)
        verdict = "agrees" if scaramuzza_worst and kb_not_worse else "differs"
    else:
        verdict = "not measured"
    out.append(Claim("calibration (Table I)", "reprojection RMS KB 0.099 ≈ Mei 0.102 < Scaramuzza 0.121 px",
                     _fmt(three, "px"), verdict))  # fmt: skip

    # Fig. 6 shows the paper's models only: Mei, Kannala-Brandt, Scaramuzza and atan.
    shown_models = (KB, MEI, SCARAMUZZA, EQUIDISTANT)
    models = {
        m: image_difference[m] for m in shown_models if math.isfinite(image_difference.get(m, math.nan))
    }
    if SCARAMUZZA in models and len(models) > 1:
        others = max(v for m, v in models.items() if m != SCARAMUZZA)
        verdict = _worse(models[SCARAMUZZA], others)
    else:
        verdict = "not measured"
    claim = "Scaramuzza differs more from the Reference than Mei, KB, atan"
    out.append(Claim("image difference (Fig. 6)", claim, _fmt(models, "grey levels"), verdict))

    ref = curves.get(REFERENCE, [])
    ratios = {n: mean_ratio(c, ref) for n, c in curves.items() if n not in (REFERENCE, THEORY)}
    shown = {n: r for n, r in ratios.items() if math.isfinite(r)}
    best_other = min(shown.values()) if shown else math.nan
    out.append(Claim("depth (Fig. 7)", "the Reference pair is the most accurate",
                     "mean RMS / Reference: " + _fmt(shown), _worse(best_other, 1.0)))  # fmt: skip
    r_true = ratios.get(TRUE_LENS, math.nan)
    out.append(
        Claim(
            "depth (Fig. 7)",
            "the ideal (true) lens model follows the Reference closely",
            f"true lens {r_true:.3g} × Reference",
            "not measured" if not math.isfinite(r_true) else ("agrees" if r_true <= CLOSE else "differs"),
        )
    )
    r_kb = ratios.get(KB, math.nan)
    out.append(
        Claim(
            "depth (Fig. 7)",
            "Kannala-Brandt is almost identical to the Reference",
            f"Kannala-Brandt {r_kb:.3g} × Reference",
            "not measured" if not math.isfinite(r_kb) else ("agrees" if r_kb <= CLOSE else "differs"),
        )
    )
    out.append(Claim("depth (Fig. 7)", "Mei is substantially worse than Kannala-Brandt",
                     f"Mei {ratios.get(MEI, math.nan):.3g} vs Kannala-Brandt {r_kb:.3g} × Reference",
                     _worse(ratios.get(MEI, math.nan), r_kb)))  # fmt: skip
    paper_three = {m: ratios[m] for m in (KB, MEI, SCARAMUZZA) if m in ratios and math.isfinite(ratios[m])}
    if SCARAMUZZA in paper_three and len(paper_three) > 1:
        verdict = _worse(paper_three[SCARAMUZZA], max(v for m, v in paper_three.items() if m != SCARAMUZZA))
    else:
        verdict = "not measured"
    out.append(Claim("depth (Fig. 7)", "Scaramuzza is the worst of KB, Mei and Scaramuzza",
                     _fmt(paper_three), verdict))  # fmt: skip
    slopes = {n: loglog_slope([p.k for p in curves[n]], [p.rms_m for p in curves[n]])
              for n in (REFERENCE, KB) if n in curves}  # fmt: skip
    good = [1.5 <= s <= 2.5 for s in slopes.values() if math.isfinite(s)]
    out.append(Claim("depth (Fig. 7, 12)", "the error grows about quadratically with distance",
                     "RMS ∝ k^p with p = " + _fmt(slopes),
                     "not measured" if not good else ("agrees" if all(good) else "differs")))  # fmt: skip
    return out
