"""Imports flow one way (cli → service → rig → calibration) and only ``cli`` loads typer and rich.

Every module of ``calibration``, ``rig`` and ``service`` is imported in a fresh interpreter, which
reports what ended up in ``sys.modules`` and which module first imported typer or rich: an
indirect import through our own modules counts as much as a direct one. One third-party path is
known and allowed: httpx (the client's HTTP library) imports rich for its own optional command
line when rich is installed. (``make lint`` checks the same contracts statically with
import-linter.)
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from typing import Any

import pytest

from tests.conftest import REPO

LIBRARY_PACKAGES = ("calibration", "rig", "service")
CLI_ONLY = ("typer", "rich")
#: Third-party modules allowed to import a CLI-only package on their own account.
ALLOWED_IMPORTERS = {"rich": {"httpx._main"}, "typer": set()}

_PROBE = textwrap.dedent(
    """
    import importlib, json, pkgutil, sys

    WATCHED = set(sys.argv[2].split(","))
    importers = {}

    class Watch:
        # Records the module whose code imports a watched package first (importlib frames skipped).
        def find_spec(self, fullname, path=None, target=None):
            if fullname in WATCHED and fullname not in importers:
                frame = sys._getframe(1)
                while frame and frame.f_globals.get("__name__", "").startswith(("importlib", "_frozen")):
                    frame = frame.f_back
                importers[fullname] = frame.f_globals.get("__name__") if frame else None
            return None

    sys.meta_path.insert(0, Watch())
    package = importlib.import_module(sys.argv[1])
    names = [package.__name__]
    for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
        if info.name.endswith(".__main__"):
            continue  # runs the program
        importlib.import_module(info.name)
        names.append(info.name)
    loaded = sorted({m.split(".")[0] for m in sys.modules})
    print(json.dumps({"modules": names, "loaded": loaded, "importers": importers}))
    """
)


def _imports_of(package: str) -> dict[str, Any]:
    res = subprocess.run(
        [sys.executable, "-c", _PROBE, package, ",".join(CLI_ONLY)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )
    assert res.returncode == 0, res.stderr
    result: dict[str, Any] = json.loads(res.stdout.strip().splitlines()[-1])
    return result


@pytest.mark.parametrize("package", LIBRARY_PACKAGES)
def test_library_packages_load_no_cli_framework_and_nothing_above_them(package: str) -> None:
    got = _imports_of(package)
    assert len(got["modules"]) > 3, got["modules"]  # the walk found the package's modules
    above = {"cli", *LIBRARY_PACKAGES[LIBRARY_PACKAGES.index(package) + 1 :]}
    assert not set(got["loaded"]) & above, (package, set(got["loaded"]) & above)
    for name in CLI_ONLY:
        importer = got["importers"].get(name)
        assert (name in got["loaded"]) == (importer is not None), (name, got["importers"])
        assert importer is None or importer in ALLOWED_IMPORTERS[name], f"{name} imported by {importer}"


def test_the_probe_sees_what_cli_loads() -> None:
    # The same probe on cli itself must name cli's own modules as the importers of typer and
    # rich, or it could not catch anything.
    got = _imports_of("cli")
    assert {"typer", "rich", "service", "rig", "calibration"} <= set(got["loaded"])
    assert all(got["importers"][name].startswith("cli.") for name in CLI_ONLY), got["importers"]
