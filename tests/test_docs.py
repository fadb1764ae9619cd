"""The documentation's links: every relative link in the README, docs/ and experiments/ names a file that exists and,
into a Markdown file, a heading it has (GitHub's anchors); docs/results.md's contents lists every section."""

from __future__ import annotations

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
LINK = re.compile(r"\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", flags=re.M | re.S)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, characters other than letters, digits, ``-``, ``_`` and spaces
    dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(path: pathlib.Path) -> set[str]:
    """The anchors of a Markdown file's headings (a repeated heading's get ``-1``, ``-2``... as on GitHub)."""
    seen: dict[str, int] = {}
    found = set()
    for heading in re.findall(r"^#{1,6} (.+)$", FENCE.sub("", path.read_text()), flags=re.M):
        base = slug(heading)
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(base if count == 0 else f"{base}-{count}")
    return found


def relative_links(path: pathlib.Path) -> list[str]:
    """Links outside code blocks that are neither URLs (``https:``, ``mailto:``...) nor bare anchors of other pages."""
    return [target for target in LINK.findall(FENCE.sub("", path.read_text())) if not re.match(r"[a-z]+:", target)]


def markdown_files() -> list[pathlib.Path]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "experiments").rglob("*.md"))]
    return [path for path in files if path.is_file()]


def test_slug_matches_github() -> None:
    assert slug("The main job (`make train`)") == "the-main-job-make-train"
    assert slug("lifts it by 6.9 ± 0.7, T = 3") == "lifts-it-by-69--07-t--3"
    assert slug("hopper/medium's `q_term_confidence`") == "hoppermediums-q_term_confidence"


@pytest.mark.parametrize("path", markdown_files(), ids=lambda path: str(path.relative_to(ROOT)))
def test_relative_links_resolve(path: pathlib.Path) -> None:
    broken = []
    for target in relative_links(path):
        file, _, fragment = target.partition("#")
        destination = (path.parent / file).resolve() if file else path
        if not destination.exists():
            broken.append(f"{target}: no such file")
        elif fragment and destination.suffix == ".md" and fragment not in anchors(destination):
            broken.append(f"{target}: no such heading in {destination.name}")
    assert not broken, broken


def test_links_are_checked() -> None:
    """The check above reads the links there are (a pattern that matched nothing would pass every file)."""
    assert sum(len(relative_links(path)) for path in markdown_files()) >= 50
    assert "docs/results.md" in relative_links(ROOT / "README.md")


def test_results_contents_lists_every_section() -> None:
    results = ROOT / "docs" / "results.md"
    text = FENCE.sub("", results.read_text())
    sections = [slug(heading) for heading in re.findall(r"^## (.+)$", text, flags=re.M) if heading != "Contents"]
    contents = text.split("## Contents", 1)[1].split("\n## ", 1)[0]
    listed = [target.lstrip("#") for target in LINK.findall(contents)]
    assert listed == sections, "docs/results.md's contents must list each '## ' section, newest first, in file order"
