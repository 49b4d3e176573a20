"""The documentation is the project's own: every relative link in a tracked markdown file resolves
to a file inside the repository, and nothing points to notes a user of the package never has."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: ``[text](target)`` and ``![alt](target)`` (target up to a blank or the closing parenthesis),
#: and reference definitions ``[label]: target``.
_INLINE = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)", re.M)
_FENCE = re.compile(r"^(```|~~~).*?^\1", re.M | re.S)

#: The design notes and paper that live outside the repository (the team's, not the users').
_OUTSIDE = re.compile(r"MATH\.md|STRUCTURE\.md|ARCHITECTURE\.md|PLANTS\.md|\.\./shared|/work/shared")

#: Files other work in flight still has to rewrite (their pointers go when it lands; a file that no
#: longer points outside must leave this set, the test says so).
_NOT_YET: set[str] = set()


def _tracked(*patterns: str) -> list[Path]:
    """Tracked files matching the git pathspecs (every file under ROOT when git is unavailable)."""
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "ls-files", "--", *patterns], capture_output=True, text=True,
                             check=True, timeout=30).stdout.split()
        return [ROOT / p for p in out]
    except (OSError, subprocess.SubprocessError):
        return sorted(p for pat in patterns for p in ROOT.rglob(pat.lstrip("*/")) if ".git" not in p.parts)


def links(text: str) -> list[str]:
    """Link targets of a markdown text, code blocks and inline code left out."""
    text = _FENCE.sub("", text)
    text = re.sub(r"`[^`\n]*`", "", text)
    return _INLINE.findall(text) + _REFERENCE.findall(text)


def _relative(target: str) -> bool:
    return not (re.match(r"[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith("#"))


MARKDOWN = _tracked("*.md")


def test_the_link_parser_finds_what_a_reader_clicks():
    text = ("See [notes](docs/paper.md#errata), ![fig](figures/a%20b.png \"t\"), [web](https://x.org), [top](#x).\n"
            "```\n[not a link](nowhere.md)\n```\n`[code](nowhere.md)`\n[ref]: ../outside.md\n")
    assert links(text) == ["docs/paper.md#errata", "figures/a%20b.png", "https://x.org", "#x", "../outside.md"]
    assert [t for t in links(text) if _relative(t)] == ["docs/paper.md#errata", "figures/a%20b.png", "../outside.md"]


def test_there_are_docs_and_readme_links_to_them():
    names = {p.relative_to(ROOT).as_posix() for p in MARKDOWN}
    assert {"README.md", "docs/README.md", "docs/paper.md", "docs/certificates.md", "docs/structured.md",
            "docs/results.md"} <= names
    readme = links((ROOT / "README.md").read_text(encoding="utf-8"))
    assert any(t.startswith("docs/") for t in readme)


@pytest.mark.parametrize("md", MARKDOWN, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve_inside_the_repository(md):
    bad = []
    for target in links(md.read_text(encoding="utf-8")):
        if not _relative(target):
            continue
        path = unquote(target.split("#", 1)[0])
        dest = (md.parent / path).resolve()
        if not dest.is_relative_to(ROOT.resolve()):
            bad.append(f"{target}: outside the repository")
        elif not dest.exists():
            bad.append(f"{target}: no such file")
    assert not bad, f"{md.relative_to(ROOT)}: " + "; ".join(bad)


def test_nothing_points_to_notes_outside_the_repository():
    sources = _tracked("*.md", "*.py", "*.toml", "*.cfg", "*.txt")
    pointing = {p.relative_to(ROOT).as_posix() for p in sources
                if p.is_file() and p.name != Path(__file__).name and _OUTSIDE.search(p.read_text(errors="replace"))}
    assert pointing - _NOT_YET == set(), "point these to docs/ instead"
    assert _NOT_YET <= pointing, f"no longer pointing outside: remove {sorted(_NOT_YET - pointing)} from _NOT_YET"


def test_every_docs_file_named_in_code_or_text_exists():
    named = {}
    for p in _tracked("*.py", "*.md"):
        if p.is_file():
            for m in re.findall(r"(?<![\w/.])docs/[\w./-]*\w\.md", p.read_text(errors="replace")):
                named.setdefault(m, p.relative_to(ROOT).as_posix())
    assert "docs/paper.md" in named  # the designs' docstrings point here
    missing = {m: where for m, where in named.items() if not (ROOT / m).is_file()}
    assert not missing, missing
