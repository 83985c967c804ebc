"""``run.json``'s ``source``: the git commit of the code an evaluation ran, checked against git
itself on real repositories (this checkout and throwaway ones)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from rig.evaluate.provenance import SOURCE_ROOT, SourceRevision, source_revision

pytestmark = pytest.mark.needs_tool("git", "apt-get install git")


def git(root: Path, *args: str) -> str:
    env = {
        "GIT_AUTHOR_NAME": "t",
        "GIT_AUTHOR_EMAIL": "t@t",
        "GIT_COMMITTER_NAME": "t",
        "GIT_COMMITTER_EMAIL": "t@t",
    }
    res = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, env=env, check=True)
    return res.stdout.strip()


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    root = tmp_path / "repo"
    root.mkdir()
    git(root, "init", "-q")
    (root / "a.py").write_text("x = 1\n")
    git(root, "add", "a.py")
    git(root, "commit", "-q", "-m", "first")
    return root


def test_a_clean_checkout_gives_its_head(repo: Path) -> None:
    head = git(repo, "rev-parse", "HEAD")
    assert len(head) == 40
    assert source_revision(repo) == SourceRevision(head, dirty=False)
    assert source_revision(repo).as_json() == {"commit": head, "dirty": False}  # type: ignore[union-attr]


def test_a_changed_tracked_file_is_dirty_an_untracked_one_is_not(repo: Path) -> None:
    (repo / "notes.txt").write_text("scratch\n")
    assert source_revision(repo) == SourceRevision(git(repo, "rev-parse", "HEAD"), dirty=False)
    (repo / "a.py").write_text("x = 2\n")
    assert source_revision(repo) == SourceRevision(git(repo, "rev-parse", "HEAD"), dirty=True)
    git(repo, "commit", "-q", "-am", "second")
    second = source_revision(repo)
    assert second == SourceRevision(git(repo, "rev-parse", "HEAD"), dirty=False)


def test_outside_a_checkout_or_below_its_top_level_is_none(repo: Path, tmp_path: Path) -> None:
    plain = tmp_path / "plain"
    plain.mkdir()
    assert source_revision(plain) is None
    assert source_revision(tmp_path / "missing") is None
    # An installed package inside some other repository (a venv in a project) is not that project.
    (repo / "site-packages").mkdir()
    assert source_revision(repo / "site-packages") is None
    empty = tmp_path / "empty"
    empty.mkdir()
    git(empty, "init", "-q")
    assert source_revision(empty) is None  # no commit yet


def test_this_source_tree_is_described_as_git_describes_it() -> None:
    try:
        top = git(SOURCE_ROOT, "rev-parse", "--show-toplevel")
    except subprocess.CalledProcessError:
        assert source_revision() is None
        return
    if Path(top).resolve() != SOURCE_ROOT:
        assert source_revision() is None
        return
    changed = subprocess.run(["git", "-C", str(SOURCE_ROOT), "diff", "--quiet", "HEAD"]).returncode
    assert changed in (0, 1)
    assert source_revision() == SourceRevision(git(SOURCE_ROOT, "log", "-1", "--format=%H"), changed == 1)
