"""The user docs stay usable: README.md is at most 400 lines, names the commands CI runs (``.ci/run``'s make
targets), and every relative link in README.md and docs/ (Markdown ``[text](target)``) points to a file or folder
that exists."""

from __future__ import annotations

import pathlib
import re

REPO = pathlib.Path(__file__).resolve().parents[1]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _docs() -> list[pathlib.Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]


def test_readme_is_short():
    lines = (REPO / "README.md").read_text().splitlines()
    assert len(lines) <= 400, f"README.md has {len(lines)} lines; move details to docs/"


def test_readme_names_the_commands_ci_runs():
    targets = re.findall(r"^\s*make (\w+)", (REPO / ".ci" / "run").read_text(), flags=re.MULTILINE)
    readme = (REPO / "README.md").read_text()
    assert "test" in targets, targets
    for target in targets:
        assert f"make {target}" in readme, f"README.md does not mention `make {target}`, which .ci/run runs"


def test_relative_links_resolve():
    broken = []
    for doc in _docs():
        for target in LINK.findall(doc.read_text()):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
                continue  # a URL or an anchor in the same file
            path = (doc.parent / target.split("#", 1)[0]).resolve()
            if not path.exists():
                broken.append(f"{doc.relative_to(REPO)}: {target}")
    assert not broken, "links to missing files:\n" + "\n".join(broken)


def test_the_link_check_sees_links():
    # Control: the pattern finds the README's links (a pattern that found none would pass any docs).
    found = LINK.findall((REPO / "README.md").read_text())
    assert "docs/RESULTS.md" in found and "docs/TRAINING.md" in found
