"""Every citation of the physics reference in the code points at a section that exists in docs/physics.md."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CITE = re.compile(r"physics\.md (?:§|sections? )(\d+)(?:\s*(?:-|and)\s*§?(\d+))?")


def _sections() -> set[int]:
    text = (ROOT / "docs" / "physics.md").read_text(encoding="utf-8")
    return {int(m) for m in re.findall(r"^## (\d+)\. ", text, flags=re.MULTILINE)}


def _sources() -> list[Path]:
    out = []
    for folder in ("engine", "scenes", "service", "clients", "tests"):
        out += sorted((ROOT / folder).rglob("*.py"))
    return out + [ROOT / "README.md"]


def test_sections_are_numbered_in_order_with_the_named_ones():
    sections = _sections()
    assert sections == set(range(1, max(sections) + 1))
    text = (ROOT / "docs" / "physics.md").read_text(encoding="utf-8")
    for title in ("Paraxial rays", "Beam fields", "Eigenrays"):
        assert re.search(rf"^## \d+\. {title}$", text, flags=re.MULTILINE), title


def test_every_citation_names_an_existing_section():
    sections = _sections()
    cited, missing = 0, []
    for path in _sources():
        for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for match in CITE.finditer(line):
                cited += 1
                for group in match.groups():
                    if group is not None and int(group) not in sections:
                        missing.append(f"{path.relative_to(ROOT)}:{lineno}: {match.group(0)}")
    assert cited > 40  # the pattern really finds the citations
    assert missing == []
