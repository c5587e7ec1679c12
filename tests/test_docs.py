"""The repository's documents: every relative link resolves inside the repository."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = ["README.md", "BENCHMARKS.md", "docs/sensor.md", "docs/texture.md", "docs/learn.md",
             "docs/map.md"]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _anchor(heading):
    """GitHub's anchor of a markdown heading: lower case, punctuation dropped, spaces to '-'."""
    text = heading.lstrip("#").strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path):
    return {_anchor(line) for line in path.read_text().splitlines() if line.startswith("#")}


def _relative_links(path):
    links = LINK.findall(path.read_text())
    return [link for link in links if not re.match(r"[a-z]+:", link)]


def test_anchor_of_a_numbered_heading():
    assert _anchor("## 5. The sensor file (TOML)") == "5-the-sensor-file-toml"


@pytest.mark.parametrize("name", DOCUMENTS)
def test_relative_links_resolve(name):
    document = ROOT / name
    broken = []
    for link in _relative_links(document):
        target, _, anchor = link.partition("#")
        path = (document.parent / target).resolve() if target else document
        if not path.is_relative_to(ROOT) or not path.exists():
            broken.append(link)
        elif anchor and anchor not in _anchors(path):
            broken.append(link)
    assert broken == []


def test_readme_links_the_sensor_contract():
    assert "docs/sensor.md" in _relative_links(ROOT / "README.md")
