"""``/counters``: the counter table (:mod:`rig.counters`), what each ``/health`` and ``/metrics``
figure means; the dashboard builds its camera table from it."""

from __future__ import annotations

from fastapi import APIRouter

from rig.counters import GROUPS, counters_of
from service.schemas import CounterModel

__all__ = ["router"]

router = APIRouter(tags=["health"])


@router.get(
    "/counters",
    response_model=list[CounterModel],
    summary="Every camera, pairing and worker figure of /health and /metrics: kind, unit, meaning",
)
def get_counters() -> list[CounterModel]:
    return [CounterModel.of(spec) for group in GROUPS for spec in counters_of(group)]
