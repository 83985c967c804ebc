"""What a test needs from outside the repo: the real third-party data (``RIG_SHARED_DATA``,
default ``../shared/data``) and the tools .ci/run installs (chromium, python3-mrcal,
systemd-analyze, shellcheck, ...). Where one is missing, a local run skips the test saying why
(and the session ends with one line counting those skips, :func:`missing_inputs_line`); with
``RIG_REQUIRE_TEST_INPUTS=1``, which .ci/run sets, the test fails instead: CI never passes by
skipping what it was meant to run."""

from __future__ import annotations

import os
import shutil
from collections import Counter
from collections.abc import Iterable
from pathlib import Path
from typing import NoReturn

import pytest

__all__ = ["REQUIRE_ENV", "missing_input", "missing_inputs_line", "require_tool", "skip_reason"]

REQUIRE_ENV = "RIG_REQUIRE_TEST_INPUTS"
_PREFIX = "missing test input: "


def inputs_required() -> bool:
    return os.environ.get(REQUIRE_ENV, "") not in ("", "0")


def missing_input(what: str, detail: str) -> NoReturn:
    """Skip the calling test (fail it when :data:`REQUIRE_ENV` is set): ``what`` names the input
    (the same words for every test missing it: the summary line counts by it), ``detail`` says
    where it was looked for and how to get it."""
    if inputs_required():
        pytest.fail(
            f"{what} is missing: {detail} ({REQUIRE_ENV} is set: this run must not skip it)", pytrace=False
        )
    pytest.skip(f"{_PREFIX}{what}: {detail}")


def require_tool(tool: str, install: str) -> None:
    """The test needs ``tool`` (a path or a command on PATH); ``install`` says how to get it."""
    if not (Path(tool).is_file() or shutil.which(tool)):
        missing_input(tool, f"not installed ({install})")


def skip_reason(report: pytest.TestReport) -> str:
    """The reason a skipped test report gives."""
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2]).removeprefix("Skipped: ")
    return str(longrepr)


def missing_inputs_line(reasons: Iterable[str]) -> str | None:
    """The session's one summary line on the tests that skipped for a missing input (given every
    skip reason of the session), or None if none did."""
    counts = Counter(r.removeprefix(_PREFIX).partition(": ")[0] for r in reasons if r.startswith(_PREFIX))
    if not counts:
        return None
    parts = ", ".join(f"{n} for {what}" for what, n in counts.most_common())
    return (
        f"{sum(counts.values())} tests skipped for missing test inputs ({parts}); "
        f"RIG_SHARED_DATA points at the real data, and {REQUIRE_ENV}=1 (as in CI) fails them instead"
    )
