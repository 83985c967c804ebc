"""Which source code an evaluation ran: the git commit of the checkout holding the ``rig``
package, and whether its tracked files differed from that commit (``run.json``'s ``source``)."""

from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path

__all__ = ["SOURCE_ROOT", "SourceRevision", "source_revision"]

#: The directory holding the ``rig`` package: a git checkout's top level when run from one.
SOURCE_ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class SourceRevision:
    commit: str  # full hash of HEAD
    dirty: bool  # tracked files differ from HEAD (untracked files are not counted)

    def as_json(self) -> dict[str, str | bool]:
        return {"commit": self.commit, "dirty": self.dirty}


def _git(root: Path, *args: str) -> str | None:
    try:
        res = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return res.stdout.strip() if res.returncode == 0 else None


def source_revision(root: Path = SOURCE_ROOT) -> SourceRevision | None:
    """The revision of the git checkout whose top level is ``root``; None where ``root`` is not
    one (an installed package, or inside some other repository) or git cannot tell."""
    top = _git(root, "rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() != root.resolve():
        return None
    commit = _git(root, "rev-parse", "--verify", "HEAD")
    status = _git(root, "status", "--porcelain", "--untracked-files=no")
    if not commit or status is None:
        return None
    return SourceRevision(commit, bool(status))
