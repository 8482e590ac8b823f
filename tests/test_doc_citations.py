"""Docs and docstrings cite what a reader can open: the summaries of the authors' code in
docs/reference/ by path and section, never the specs that were not committed."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Committed records stay as they were recorded (their citations are history).
RECORDS = ("benchmarks/RESULTS.md", "docs/results/")
SEARCHED = ("README.md", "assets", "benchmarks", "docs", "envs_mjx", "jaml", "tests")

# A spec by its old bare name (not under docs/reference/), or "reference §N" without a page.
_BARE = re.compile(r"(?<![\w/.])(?:reference/)?(suite_reference\.md|aml_reference\.md|"
                   r"fig9_reference\.md|perf_anchors\.md)|(?<![\w/.])reference §\d")
# The pages themselves (they link each other by file name) and this test.
_OWN = ("docs/reference/", "tests/test_doc_citations.py")
_CITED = re.compile(r"docs/reference/(\w+\.md)(?:`?,? (§\d+[a-z]?))?")


def _texts():
    for top in SEARCHED:
        paths = [ROOT / top] if (ROOT / top).is_file() else sorted((ROOT / top).rglob("*"))
        for path in paths:
            name = path.relative_to(ROOT).as_posix()
            if path.suffix in (".md", ".py") and not name.startswith(RECORDS):
                yield name, path.read_text()


def _sections(page: Path) -> set[str]:
    return set(re.findall(r"^#+ (§\d+[a-z]?)\b", page.read_text(), re.M))


def test_no_citation_names_a_spec_outside_the_repository():
    bare = [f"{name}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)}"
            for name, text in _texts() if not name.startswith(_OWN)
            for m in _BARE.finditer(text)]
    assert not bare, "cite docs/reference/PAGE.md §N instead:\n" + "\n".join(bare)


def test_every_cited_reference_page_and_section_exists():
    missing = []
    for name, text in _texts():
        if name == _OWN[1]:
            continue
        for page, section in _CITED.findall(text):
            path = ROOT / "docs" / "reference" / page
            if not path.is_file():
                missing.append(f"{name}: docs/reference/{page}")
            elif section and section not in _sections(path):
                missing.append(f"{name}: docs/reference/{page} {section}")
    assert not missing, "\n".join(sorted(set(missing)))
