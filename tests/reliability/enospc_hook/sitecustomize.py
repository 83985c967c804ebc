"""Injected full disk for a ``rig`` subprocess, used only where no small real file system can be
mounted: with ``FAKE_DISK_ROOT`` and ``FAKE_DISK_BUDGET_BYTES`` set, files that rig.recording
writes under that root share the byte budget; past it a write is cut short and fails with ENOSPC,
as the kernel does on a full disk."""

from __future__ import annotations

import os

if os.environ.get("FAKE_DISK_ROOT") and os.environ.get("FAKE_DISK_BUDGET_BYTES"):
    from tests.reliability.fake_disk import install

    install(os.environ["FAKE_DISK_ROOT"], int(os.environ["FAKE_DISK_BUDGET_BYTES"]))
