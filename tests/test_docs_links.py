"""The docs hold together: every relative link in README.md and docs/ leads to a file that exists
(and, with ``#anchor``, to a heading of that file), README.md stays short, and nothing in the
repository points at design sections or issues by number instead of at a docs page."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README_MAX_LINES = 200

_FENCE = re.compile(r"^\s*(```|~~~)")
_INLINE_CODE = re.compile(r"`+[^`]*`+")
# [text](target) and ![alt](target); the target ends at whitespace or the closing parenthesis.
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
_EXTERNAL = ("http://", "https://", "mailto:", "ftp://")
# Built from parts so that this file does not contain what it looks for.
_FORBIDDEN = re.compile("DESIGN " + "\u00a7|issue " + "#", re.IGNORECASE)
_SKIP_DIRS = {".git", ".venv", "__pycache__", ".mypy_cache", ".pytest_cache", ".ruff_cache", ".hypothesis"}


def markdown_files() -> list[Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]


def _prose_lines(text: str) -> list[tuple[int, str]]:
    """(line number, line) outside fenced code blocks, inline code removed."""
    out: list[tuple[int, str]] = []
    fenced = False
    for number, line in enumerate(text.splitlines(), 1):
        if _FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            out.append((number, _INLINE_CODE.sub("", line)))
    return out


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: markup and punctuation dropped, lower case, spaces to
    hyphens (letters, digits, ``_`` and ``-`` kept)."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text only
    text = text.replace("`", "").replace("*", "").lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a markdown file, duplicates numbered as GitHub numbers them."""
    seen: dict[str, int] = {}
    out: set[str] = set()
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            continue
        match = None if fenced else _HEADING.match(line)
        if match is None:
            continue
        slug = github_slug(match.group(2))
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def links(path: Path) -> list[tuple[int, str]]:
    """(line number, target) of every link in the prose of a markdown file."""
    return [
        (number, m.group(1))
        for number, line in _prose_lines(path.read_text(encoding="utf-8"))
        for m in _LINK.finditer(line)
    ]


def broken_links(path: Path) -> list[str]:
    problems = []
    for number, target in links(path):
        if target.startswith(_EXTERNAL):
            continue
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / file_part).resolve() if file_part else path
        where = f"{path.relative_to(REPO)}:{number}: {target}"
        if not dest.exists():
            problems.append(f"{where}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            problems.append(f"{where}: no heading with anchor #{anchor} in {dest.relative_to(REPO)}")
    return problems


def test_slugs_follow_github() -> None:
    assert github_slug("A frame's path from camera to HTTP") == "a-frames-path-from-camera-to-http"
    assert github_slug("Depth from a recording (`rig process`)") == "depth-from-a-recording-rig-process"
    assert github_slug("Real cameras (V4L2/UVC)") == "real-cameras-v4l2uvc"
    assert github_slug("`rig.yaml`") == "rigyaml"
    assert github_slug("kannala_brandt") == "kannala_brandt"


def test_link_checker_finds_a_broken_link_and_a_missing_anchor(tmp_path: Path) -> None:
    page = REPO / "docs" / "README.md"
    assert links(page), "the docs index links to every page"
    fake = tmp_path / "page.md"
    fake.write_text("# Title\n\n[ok](#title) [bad](#nowhere) [gone](missing.md) `[code](x.md)`\n")
    targets = [t for _, t in links(fake)]
    assert targets == ["#title", "#nowhere", "missing.md"]
    assert anchors(fake) == {"title"}


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(path: Path) -> None:
    assert broken_links(path) == []


def test_every_docs_page_is_in_the_index() -> None:
    index = REPO / "docs" / "README.md"
    listed = {(index.parent / t.partition("#")[0]).resolve() for _, t in links(index)}
    pages = {p.resolve() for p in (REPO / "docs").glob("*.md") if p != index}
    assert pages <= listed, sorted(str(p.relative_to(REPO)) for p in pages - listed)


def test_readme_stays_short() -> None:
    lines = (REPO / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines"


def _repository_files() -> list[Path]:
    """Tracked and untracked (not ignored) files; a walk where git is unavailable."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=REPO,
            capture_output=True,
            check=True,
        ).stdout
        return [REPO / name for name in out.decode().split("\0") if name]
    except (OSError, subprocess.CalledProcessError):
        return [
            p
            for p in REPO.rglob("*")
            if p.is_file() and not _SKIP_DIRS.intersection(p.relative_to(REPO).parts)
        ]


def test_nothing_points_at_design_sections_or_issue_numbers() -> None:
    found = []
    for path in _repository_files():
        if not path.is_file():  # deleted but still listed
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue  # images and other binary files
        for number, line in enumerate(text.splitlines(), 1):
            if _FORBIDDEN.search(line):
                found.append(f"{path.relative_to(REPO)}:{number}: {line.strip()}")
    assert found == [], "point at a docs/ page section instead:\n" + "\n".join(found)
