"""The README and the documentation say what the code does: short, links that resolve, the layer map that
lint-imports enforces, and no ticket numbers. The strict MkDocs build (``python3 run.py test``) checks the site's
own links and the docstrings of the API reference."""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PRODUCT_TEXT = [README, ROOT / "CHANGELOG.md", ROOT / "config" / "README.md", *sorted(DOCS.rglob("*.md"))]


def test_readme_is_short():
    assert len(README.read_text().splitlines()) <= 200


def test_readme_links_resolve():
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", README.read_text())
    local = [t for t in targets if not re.match(r"[a-z]+:", t)]
    assert local, "the README links to the documentation"
    missing = [t for t in local if not (ROOT / t).exists()]
    assert not missing, f"README links to files that do not exist: {missing}"


def test_readme_names_the_two_commands_and_the_papers():
    text = README.read_text()
    head = "\n".join(text.splitlines()[:10])
    assert "python3 run.py study" in head and "python3 run.py test" in head
    assert "Liu" in text and "Zha" in text   # the two papers, named by their authors


def test_layer_map_in_the_docs_is_the_import_contract():
    contract = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    layers = next(c for c in contract if c["type"] == "layers")["layers"]
    want = [sorted(p.strip().removeprefix("calib.") for p in layer.split("|")) for layer in layers]
    block = re.search(r"```text\n(.*?)```", (DOCS / "layout.md").read_text(), re.S).group(1)
    got = [sorted(p.strip().rstrip("/") for p in line.split("  ")[0].split("|")) for line in block.splitlines()
           if line.strip()]
    assert got == want


def test_no_process_words_in_product_text():
    pattern = re.compile(r"issue\s+#?\d|\bround\b|\brounds\b|the brief|session of work", re.I)
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}" for p in PRODUCT_TEXT
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not hits, "\n".join(hits)


def test_no_placeholders_in_the_user_documents():
    """A number a user reads is measured or absent: no TODO / TBD placeholder in the README or the docs."""
    pattern = re.compile(r"\bTODO\b|\bTBD\b|TODO-NUMBER")
    pages = [ROOT / "README.md", ROOT / "config" / "README.md", *sorted(DOCS.rglob("*.md"))]
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}" for p in pages
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not hits, "\n".join(hits)


def test_every_doc_page_is_in_the_navigation():
    nav = (ROOT / "mkdocs.yml").read_text()
    pages = [p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")]
    assert pages and all(page in nav for page in pages), sorted(set(pages) - set(re.findall(r"[\w/-]+\.md", nav)))
