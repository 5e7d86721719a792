"""The README and the pages in docs/: every relative link resolves (the file, and the heading an
anchor names, by GitHub's slug rules), every page is one click from the README, and the README's
first screen holds exactly the two commands."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = sorted((ROOT / "docs").glob("*.md"))
FIRST_SCREEN_LINES = 40
THE_TWO_COMMANDS = [
    "bash setup.sh && .venv/bin/abyss up",
    "bash setup.sh && .venv/bin/python -m pytest",
]

FENCE = re.compile(r"^(```|~~~).*?^\1[ \t]*$", re.MULTILINE | re.DOTALL)
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1", re.DOTALL)
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^#{1,6}[ \t]+(.+?)[ \t]*#*[ \t]*$", re.MULTILINE)


def prose(text: str) -> str:
    """The Markdown without its fenced blocks and code spans (where `](` is not a link)."""
    return CODE_SPAN.sub("", FENCE.sub("", text))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: its text (no Markdown marks) in lower case, every
    character but letters, digits, '_', '-' and spaces dropped, spaces made '-'."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading).lower()  # a link: its text
    text = "".join(ch for ch in text if ch.isalnum() or ch in "_- ")
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every anchor a Markdown file has, duplicates numbered as GitHub numbers them."""
    seen: dict[str, int] = {}
    found = set()
    for match in HEADING.finditer(FENCE.sub("", path.read_text())):
        base = slug(match.group(1))
        count = seen.get(base, 0)
        found.add(base if count == 0 else f"{base}-{count}")
        seen[base] = count + 1
    return found


def relative_links(path: Path) -> list[str]:
    return [
        target
        for target in LINK.findall(prose(path.read_text()))
        if not re.match(r"^[a-z][a-z0-9+.-]*:", target)  # http:, https:, mailto: ...
    ]


def broken_links(path: Path) -> list[str]:
    """Each relative link of `path` that names no file, or a heading that file lacks."""
    broken = []
    for target in relative_links(path):
        file_part, _, anchor = target.partition("#")
        resolved = (path.parent / file_part).resolve() if file_part else path
        if not resolved.exists():
            broken.append(f"{target}: no file {resolved}")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            broken.append(f"{target}: no heading '#{anchor}' in {resolved.name}")
    return broken


@pytest.mark.parametrize("path", [README, *PAGES], ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(path: Path) -> None:
    assert relative_links(path), f"{path.name} links nowhere"
    assert broken_links(path) == []


def test_a_broken_link_or_anchor_is_caught(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    (tmp_path / "other.md").write_text("# Other\n\n## The operator's view: `abyss op`\n")
    page.write_text(
        "# Page\n\n[fine](other.md#the-operators-view-abyss-op) [self](#page) "
        "[gone](missing.md) [no heading](other.md#nowhere) `[code](missing.md)`\n"
    )
    assert broken_links(page) == [
        f"missing.md: no file {tmp_path / 'missing.md'}",
        "other.md#nowhere: no heading '#nowhere' in other.md",
    ]


@pytest.mark.parametrize(
    ("heading", "anchor"),
    [
        ("What `abyss up` shows and leaves", "what-abyss-up-shows-and-leaves"),
        ("Stations: pure cores in I/O shells", "stations-pure-cores-in-io-shells"),
        ("ROS 2 and MCAP", "ros-2-and-mcap"),
        ("The operator's view", "the-operators-view"),
        ("linkemu, scene_stream", "linkemu-scene_stream"),
    ],
)
def test_slugs_follow_github(heading: str, anchor: str) -> None:
    assert slug(heading) == anchor


def test_every_docs_page_is_one_click_from_the_readme() -> None:
    linked = {(ROOT / target.partition("#")[0]).resolve() for target in relative_links(README)}
    assert PAGES
    assert [page.name for page in PAGES if page.resolve() not in linked] == []


def test_the_first_screen_holds_exactly_the_two_commands() -> None:
    first_screen = "\n".join(README.read_text().splitlines()[:FIRST_SCREEN_LINES])
    blocks = re.findall(r"^```(\w*)\n(.*?)^```", first_screen, re.MULTILINE | re.DOTALL)
    bash = [body for lang, body in blocks if lang in ("bash", "sh", "shell", "console")]
    assert len(bash) == 1, "one bash block on the first screen"
    commands = [line.split("#")[0].strip() for line in bash[0].splitlines() if line.strip()]
    assert commands == THE_TWO_COMMANDS
