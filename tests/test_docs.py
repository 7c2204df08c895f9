"""The README and the pages of docs/ link to each other by relative links; each must reach a file
that exists and, with an anchor, a heading of that file (anchors as GitHub makes them). The names
of oodmon they cite (`oodmon.envs.parse_variant`, a code block's imports) must exist: a rename
that leaves a page behind fails here."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

from tests.helpers import DOC_PAGES

ROOT = Path(__file__).resolve().parents[1]
PAGES = DOC_PAGES


def anchors(path: Path) -> set[str]:
    """GitHub's anchor of each heading: lower case, punctuation but '-' and '_' dropped, spaces to '-'."""
    text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.DOTALL | re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
            for heading in re.findall(r"^#{1,6} (.+)$", text, flags=re.MULTILINE)}


def test_anchors_are_githubs():
    assert {"the-papers-benchmark", "trained-inside-vecnormalize", "five-trials-beside-the-papers"} <= (
        anchors(ROOT / "docs" / "bench.md") | anchors(ROOT / "docs" / "your-policy.md"))


def test_every_relative_link_reaches_a_file_and_its_heading():
    broken = []
    for page in PAGES:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if not file.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and anchor not in anchors(file):
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
    assert not broken, broken


def test_every_page_is_listed_in_the_readme_and_in_the_docs_index():
    readme, index = (ROOT / "README.md").read_text(), (ROOT / "docs" / "README.md").read_text()
    for page in PAGES[1:]:
        if page.name != "README.md":
            assert f"](docs/{page.name})" in readme, page.name
            assert f"]({page.name})" in index, page.name


def _cited(name: str) -> bool:
    """Whether a dotted name (``oodmon.monitor.sb3_callback.MonitorCallback``) is a module or an attribute of one."""
    parts = name.split(".")
    for split in range(len(parts), 0, -1):
        try:
            found = importlib.import_module(".".join(parts[:split]))
        except ImportError:
            continue
        for attribute in parts[split:]:
            if not hasattr(found, attribute):
                return False
            found = getattr(found, attribute)
        return True
    return False


def test_every_name_of_oodmon_the_pages_cite_exists():
    assert _cited("oodmon.envs.parse_variant") and not _cited("oodmon.envs.parse_varient")
    readmes = [*PAGES, ROOT / "oodmon/zoo/README.md", ROOT / "benchmarks/README.md", *sorted(ROOT.glob("results/*/README.md"))]
    missing, imports = [], 0
    for page in readmes:
        text = page.read_text()
        missing += [f"{page.relative_to(ROOT)}: {name}" for name in sorted(set(re.findall(r"`(oodmon(?:\.\w+)+)", text)))
                    if not _cited(name)]
        code = re.findall(r"```python\n(.*?)```", text, re.DOTALL) + re.findall(r'python -c "\n(.*?)\n"', text, re.DOTALL)
        for node in (node for block in code for node in ast.walk(ast.parse(block))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("oodmon"):
                imports += len(node.names)
                missing += [f"{page.relative_to(ROOT)}: from {node.module} import {alias.name}" for alias in node.names
                            if not _cited(f"{node.module}.{alias.name}")]
    assert imports >= 10 and not missing, missing  # 15 imports on 2026-12-04
