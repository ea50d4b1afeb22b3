"""Documentation cited by the code lives in this repository, and every numbered citation resolves.

* No ``.py`` or ``.md`` file cites the notes that were kept outside the repository (issue #20): a contributor could
  not follow them. Their facts are restated in ``docs/method.md``, ``docs/robosuite.md`` and
  ``docs/data_contract.md``.
* Every ``docs/<name>.md §N`` (or ``§N.M``; lists such as ``§5, §10`` are checked item by item) names an existing
  file under ``docs/`` that has a heading numbered ``N`` (``## N. Title`` or ``### N.M Title``).

Pure file reading; ``.venv``, ``outputs``, ``.git`` and tool caches are skipped.
"""

from __future__ import annotations

import os
import re
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SKIP_DIRS = {".venv", "outputs", ".git", ".pytest_cache", ".ruff_cache", "__pycache__", "node_modules"}
SUFFIXES = (".py", ".md")
THIS_FILE = Path(__file__).resolve()

# Out-of-repo documents (split so that this file does not cite them itself).
FORBIDDEN = re.compile(
    "|".join(
        (
            "model" + "_spec",
            "robosuite" + "_notes",
            "lerobot" + "_notes",
            r"DESIGN\.md",
            r"\.\./" + "shared",
            "shared" + "/reference",
        )
    )
)
# ``docs/<name>.md`` (optionally closed by a backtick, bracket or parenthesis), then one or more ``§N[.M]``
# separated by spaces, commas or "and".
CITATION = re.compile(r"docs/([A-Za-z0-9_\-]+\.md)[`)\]]*((?:(?:\s*,\s*|\s+and\s+|\s+)§\s*\d+(?:\.\d+)*)+)")
SECTION = re.compile(r"§\s*(\d+(?:\.\d+)*)")
HEADING = re.compile(r"^#{1,6}\s+(\d+(?:\.\d+)*)\.?\s", re.M)


def _files() -> list[Path]:
    out = []
    for dirpath, dirnames, filenames in os.walk(ROOT):
        dirnames[:] = [d for d in dirnames if d not in SKIP_DIRS and not d.endswith(".egg-info")]
        out += [Path(dirpath) / f for f in filenames if f.endswith(SUFFIXES)]
    return sorted(p for p in out if p.resolve() != THIS_FILE)


@cache
def _sections(doc: str) -> frozenset[str] | None:
    """Heading numbers of ``docs/<doc>``, or None if there is no such file."""
    path = ROOT / "docs" / doc
    if not path.is_file():
        return None
    return frozenset(HEADING.findall(path.read_text(encoding="utf-8")))


def _where(path: Path, text: str, pos: int) -> str:
    return f"{path.relative_to(ROOT)}:{text.count(chr(10), 0, pos) + 1}"


def test_no_citation_of_documents_outside_the_repository() -> None:
    bad = []
    for path in _files():
        text = path.read_text(encoding="utf-8", errors="replace")
        bad += [f"{_where(path, text, m.start())}: {m.group(0)!r}" for m in FORBIDDEN.finditer(text)]
    assert not bad, (
        "citations of documents outside the repository (cite docs/*.md §N instead):\n" + "\n".join(bad)
    )


def test_every_numbered_docs_citation_resolves() -> None:
    bad, found = [], 0
    for path in _files():
        text = path.read_text(encoding="utf-8", errors="replace")
        for m in CITATION.finditer(text):
            doc, sections = m.group(1), _sections(m.group(1))
            for number in SECTION.findall(m.group(2)):
                found += 1
                if sections is None:
                    bad.append(f"{_where(path, text, m.start())}: docs/{doc} does not exist")
                elif number not in sections:
                    bad.append(f"{_where(path, text, m.start())}: docs/{doc} has no section {number}")
    assert not bad, "unresolved docs citations:\n" + "\n".join(bad)
    assert found > 0, "no docs/<name>.md §N citation found: the pattern no longer matches the code's style"


def test_the_cited_docs_number_their_sections() -> None:
    for doc in ("method.md", "robosuite.md", "data_contract.md"):
        sections = _sections(doc)
        assert sections, f"docs/{doc} is missing or has no numbered headings (## N. Title / ### N.M Title)"
