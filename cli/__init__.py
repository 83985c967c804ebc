"""The ``rig`` subcommands that live in this package; ``service.cli`` mounts them with ``serve``.

Each module registers its own commands so they can be worked on independently.
"""

from __future__ import annotations

import typer

from rig.cli import calibrate, devices, evaluate, lut, process, record, sim

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    """Add every ``rig`` package command to ``app`` (DESIGN §7 order)."""
    for module in (process, record, devices, calibrate, lut, sim, evaluate):
        module.register(app)
