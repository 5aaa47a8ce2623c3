"""README.md is a front page: at most 200 lines, starting with the two commands that work on a
fresh machine, linking every page of docs/; every relative link in README.md and docs/*.md
points at a file that exists (and a heading that exists, for links with an #anchor)."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
README = REPO / "README.md"
PAGES = (README, *sorted((REPO / "docs").glob("*.md")))

_CODE_BLOCK = re.compile(r"^```.*?^```", re.S | re.M)
_INLINE_CODE = re.compile(r"`[^`\n]*`")
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def test_readme_is_at_most_200_lines():
    assert len(README.read_text().splitlines()) <= 200


def test_readme_starts_with_make_demo_and_make_test():
    lines = README.read_text().splitlines()
    assert lines[:3] == ["# rigcal", "", "```bash"]
    assert lines[3].startswith("make demo ") and lines[4].startswith("make test ") and lines[5] == "```"
    makefile = (REPO / "Makefile").read_text()
    for target in ("demo", "test"):  # both targets create .venv first: they work on a fresh machine
        assert re.search(rf"^{target}: \$\(STAMP\)$", makefile, re.M), target
    assert re.search(r"^\$\(STAMP\): .*\n\ttest -d \$\(VENV\) \|\| \$\(PYTHON\) -m venv", makefile, re.M)


def test_readme_links_every_docs_page():
    text = README.read_text()
    missing = [p.name for p in PAGES[1:] if f"](docs/{p.name})" not in text]
    assert not missing, f"README.md links no docs/{missing}"


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped (not - and _), spaces -> -."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip()).lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in _CODE_BLOCK.sub("", page.read_text()).splitlines():
        m = re.match(r"#{1,6} +(.*?) *#*$", line)
        if m:
            base = slug(m.group(1))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return out


def links(page: Path) -> list[str]:
    text = _INLINE_CODE.sub("", _CODE_BLOCK.sub("", page.read_text()))
    return [m.group(1) for m in _LINK.finditer(text)]


def test_slug_follows_github():
    assert slug("Frames in outputs (the frame contract)") == "frames-in-outputs-the-frame-contract"
    assert slug("8. Re-check your vehicle") == "8-re-check-your-vehicle"
    assert slug("Fleets: `rigcal check --batch`") == "fleets-rigcal-check---batch"
    assert slug("Why the paper's MCPE rows differ") == "why-the-papers-mcpe-rows-differ"


def test_every_relative_link_resolves():
    checked, broken = 0, []
    for page in PAGES:
        for target in links(page):
            if re.match(r"[a-z][a-z0-9+.-]*:", target):  # https:, mailto:, ...
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            checked += 1
            if not dest.exists():
                broken.append(f"{page.relative_to(REPO)}: {target} (no such file)")
            elif anchor and (dest.suffix != ".md" or anchor not in anchors(dest)):
                broken.append(f"{page.relative_to(REPO)}: {target} (no such heading)")
    assert checked >= 100
    assert not broken, "\n".join(broken)


def test_the_link_check_finds_a_broken_link(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Top\n\n[ok](#top), [gone](other.md), [bad anchor](#nope)\n\n```\n[in code](x.md)\n```\n")
    assert links(page) == ["#top", "other.md", "#nope"]
    assert anchors(page) == {"top"}
