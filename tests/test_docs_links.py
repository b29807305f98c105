"""Every local link of README.md and docs/**/*.md resolves: the file (or folder) exists and a ``#anchor`` names a
heading of the target page, slugged as GitHub slugs it. External links (http, https, mailto) are not fetched."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]

_FENCE = re.compile(r"^\s*(```|~~~)")
_HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
_INLINE_CODE = re.compile(r"`+[^`]*`+")
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_REFERENCE = re.compile(r"^ {0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)")
_EXTERNAL = ("http://", "https://", "mailto:", "ftp://")


def _prose_lines(text: str) -> list[str]:
    """The page's lines outside fenced code blocks (a ``#`` or a link inside a fence is code, not markdown)."""
    lines, fenced = [], False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
        elif not fenced:
            lines.append(line)
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: its rendered text lower-cased, punctuation dropped, spaces as hyphens.

    >>> slug("The default study on world v2 (`tau6r`)")
    'the-default-study-on-world-v2-tau6r'
    """
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading renders as its text
    text = re.sub(r"<[^>]+>", "", text).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every heading anchor of ``page``; a repeated heading gets ``-1``, ``-2``, ... as on GitHub."""
    seen: dict[str, int] = {}
    out = set()
    for line in _prose_lines(page.read_text(encoding="utf-8")):
        m = _HEADING.match(line)
        if not m:
            continue
        base = slug(m.group(2))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def links(page: Path) -> list[str]:
    """The link targets of ``page`` (inline, images and reference definitions), code left out."""
    found = []
    for line in _prose_lines(page.read_text(encoding="utf-8")):
        prose = _INLINE_CODE.sub("", line)
        found += _LINK.findall(prose)
        ref = _REFERENCE.match(prose)
        if ref:
            found.append(ref.group(1))
    return found


def broken_links(page: Path) -> list[str]:
    """``page``'s local links that do not resolve, each as ``target (why)``; external links are not checked."""
    broken = []
    for target in links(page):
        if target.startswith(_EXTERNAL):
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{target} (no heading '#{anchor}' in {dest.name})")
    return broken


def test_the_checker_finds_a_bad_file_and_a_bad_anchor_and_passes_good_ones(tmp_path: Path) -> None:
    (tmp_path / "other.md").write_text("# Other page\n\n## A section (`code`), τ too\n\n## A section (`code`), τ too\n")
    (tmp_path / "fig.png").write_bytes(b"")
    page = tmp_path / "page.md"
    page.write_text(
        "# Page\n\nGood: [other](other.md), [section](other.md#a-section-code-τ-too),"
        " [again](other.md#a-section-code-τ-too-1), ![fig](fig.png), [here](#page), [web](https://example.com/x).\n"
        "Bad: [gone](missing.md) and [nowhere](other.md#no-such-heading).\n\n"
        "```\n[in code](not_checked.md)\n```\n`[inline](not_checked_either.md)`\n\n[ref]: missing_too.md\n")
    assert broken_links(page) == ["missing.md (no such file)",
                                  "other.md#no-such-heading (no heading '#no-such-heading' in other.md)",
                                  "missing_too.md (no such file)"]


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_every_local_link_resolves(page: Path) -> None:
    assert broken_links(page) == []
