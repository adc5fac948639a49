"""The README and the pages under docs/: short README, the design page present, and every relative link resolves.

A link resolves when its file exists (relative to the page that holds it) and, if it carries a ``#fragment``,
when the target Markdown page has a heading whose GitHub slug is that fragment. The slug rule is GitHub's:
lower case, drop every character that is not a letter, digit, space, hyphen or underscore, spaces to hyphens,
and a repeated heading gets ``-1``, ``-2``, ... appended.
"""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README] + sorted((ROOT / "docs").glob("*.md"))

# [text](target) and ![alt](target); the target stops at whitespace or ')'; an optional "title" may follow.
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^(```|~~~)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")


def _strip_code(text: str) -> list[str]:
    """The page's lines outside fenced code blocks, with inline code spans blanked (links inside code are text)."""
    lines, in_fence = [], False
    for line in text.splitlines():
        if FENCE.match(line.strip()):
            in_fence = not in_fence
            continue
        if not in_fence:
            lines.append(re.sub(r"`[^`]*`", "``", line))
    return lines


def github_slug(heading: str) -> str:
    """GitHub's anchor for a heading's text (inline markup removed first)."""
    text = re.sub(r"`([^`]*)`", r"\1", heading)  # code spans keep their text
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)  # links keep their text
    text = re.sub(r"(?<!\w)_{1,3}(\S(?:.*?\S)?)_{1,3}(?!\w)", r"\1", text)  # _emphasis_, not snake_case
    text = text.strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every heading anchor of a Markdown page, GitHub-style, duplicates numbered."""
    seen: dict[str, int] = {}
    out = set()
    in_fence = False
    for line in page.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line.strip()):
            in_fence = not in_fence
            continue
        m = None if in_fence else HEADING.match(line)
        if m:
            slug = github_slug(m.group(2))
            n = seen.get(slug, 0)
            out.add(slug if n == 0 else f"{slug}-{n}")
            seen[slug] = n + 1
    return out


def relative_links(page: Path) -> list[str]:
    """Links of a page that point inside the repository (no scheme, no mail address)."""
    links = []
    for line in _strip_code(page.read_text(encoding="utf-8")):
        for target in LINK.findall(line):
            if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target):  # http:, https:, mailto:
                continue
            links.append(target)
    return links


def broken_links(page: Path) -> list[str]:
    bad = []
    for target in relative_links(page):
        path_part, _, fragment = target.partition("#")
        dest = page if path_part == "" else (page.parent / path_part).resolve()
        if not dest.exists():
            bad.append(f"{target}: no such file")
            continue
        if fragment and dest.suffix == ".md" and fragment not in anchors(dest):
            bad.append(f"{target}: no heading '#{fragment}' in {dest.relative_to(ROOT)}")
    return bad


def test_slug_rule_matches_github_examples():
    # GitHub's anchors for headings of this shape (checked on github.com rendering conventions)
    assert github_slug("Known limits") == "known-limits"
    assert github_slug("Closed loop at 20°/s") == "closed-loop-at-20s"
    assert github_slug("Paper 002 Table 3 (`bench_identify_paper002.py`)") == "paper-002-table-3-bench_identify_paper002py"
    assert github_slug("3CMOS colour: registration, fusion") == "3cmos-colour-registration-fusion"


def test_readme_at_most_250_lines():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= 250, f"README.md has {n} lines"


def test_design_page_present_and_linked_from_readme():
    assert (ROOT / "docs" / "design.md").is_file()
    assert any(t.split("#")[0] == "docs/design.md" for t in relative_links(README))


def test_every_docs_page_is_linked_from_readme_or_another_page():
    linked = set()
    for page in PAGES:
        for target in relative_links(page):
            path_part = target.partition("#")[0]
            if path_part:
                linked.add((page.parent / path_part).resolve())
    orphans = [p.name for p in PAGES[1:] if p.resolve() not in linked]
    assert not orphans, f"pages no other page links: {orphans}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    assert relative_links(page) or page != README, "README.md links nothing"
    assert broken_links(page) == []
