"""Every document the repository cites is in the repository (issue 37).

- A reference to a document (a ``*.md`` path, or ``README``) in the code, the tests, the
  benchmarks, the tools, the scenes and the docs resolves to a file of the repository;
  where it names a section — ``§3.1``, ``#anchor``, ``, *Heading*`` or ``, "Heading"``
  right after the path — that section exists (a heading that starts with the cited
  words, a heading numbered so, or a heading whose anchor it is).
- Every relative link in ``README.md`` and ``docs/**/*.md`` resolves, anchors included.
- ``README.md`` stays a page a person reads: at most 250 lines.
- ``docs/index.md`` links every document under ``docs/``.

The checks are plain functions over a root directory, so the last test can run them on a
small broken tree and see that they fail.
"""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Where references are looked for, and in which files.
SCANNED = ("flexarm_ros", "test", "bench", "tools", "examples", "config", "docs", ".ci")
TOP_FILES = ("README.md", "setup.py", "setup.cfg", "package.xml")
SUFFIXES = {".py", ".md", ".yaml", ".yml", ".cfg", ".toml", ".txt", ".xml", ""}
README_LIMIT = 250

#: ``.md`` names that are not documents of the repository: files the commands write
#: (``flexarm compare --report`` writes ``report.md``, ``sensitivity --markdown FILE.md``)
#: and names the tests give their temporary outputs.
NOT_DOCUMENTS = {"report.md", "FILE.md", "s.md", "calibration.md", "accuracy_table.md",
                 "self.md", "rep.md"}

_PATH = re.compile(r"(?<![\w/.:-])((?:/|\.{1,2}/)?(?:[\w.-]+/)*[\w-][\w.-]*\.md)(?![\w/])")
_README = re.compile(r"(?<![\w/.-])(README)(?![\w./-])")
_ANCHOR = re.compile(r"\A#([\w-]+)")
_NUMBER = re.compile(r"\A[`\])]*(?:,\s*|\s*)§\s*(\d+(?:\.\d+)*)")
_TITLE = re.compile(r"\A[`\])]*(?:,\s*|\s+)(?:\*([^*\s][^*]{0,100}?)\*(?!\*)|\"([^\"\s][^\"]{0,100}?)\")")
_LINK = re.compile(r"(?<!!)\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)\)")
_IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
_FENCE = re.compile(r"^\s*(```|~~~)")
_LEAD = re.compile(r"^\s*(?:[-*]\s+)?\*\*([^*]+?)\*\*")


# --------------------------------------------------------------------------- helpers
def _files(root: Path) -> list[Path]:
    found = [root / name for name in TOP_FILES if (root / name).is_file()]
    for top in SCANNED:
        base = root / top
        if not base.is_dir():
            continue
        for path in sorted(base.rglob("*")):
            if path.name == Path(__file__).name:          # this file's examples are broken
                continue
            if (path.is_file() and path.suffix in SUFFIXES and "__pycache__" not in path.parts
                    and (path.suffix or path.parent.name == ".ci")):
                found.append(path)
    return found


def _plain(text: str) -> str:
    """A heading or a cited title as compared: no markup, one space, lower case."""
    text = re.sub(r"[`*_]", "", text)
    text = re.sub(r"\s*\n\s*(?:#+:?)?\s*", " ", text)   # a title wrapped in a comment
    return " ".join(text.split()).strip(" .:,").lower()


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]", "", heading).strip().lower()
    kept = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in "LNM")
    return kept.replace(" ", "-")


def headings(path: Path, leads: bool = False) -> list[str]:
    """The headings of a Markdown file, outside fenced code; with ``leads`` also the bold
    leads that open a paragraph (``**The trapezoid rule** (since …)``), which the docs use
    as sub-sections."""
    out, fenced = [], False
    for line in path.read_text(encoding="utf-8").splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            continue
        m = None if fenced else _HEADING.match(line)
        if m:
            out.append(m.group(2))
        elif leads and not fenced:
            m = _LEAD.match(line)
            if m:
                out.append(m.group(1))
    return out


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    result = set()
    for h in headings(path):
        s = slug(h)
        n = seen.get(s, 0)
        seen[s] = n + 1
        result.add(s if n == 0 else f"{s}-{n}")
    text = path.read_text(encoding="utf-8")
    result.update(re.findall(r"<a\s+(?:id|name)=\"([^\"]+)\"", text))
    return result


def _has_number(path: Path, number: str) -> bool:
    pattern = re.compile(rf"\A(?:§\s*)?{re.escape(number)}(?:\.?\s|\.\Z|\Z)")
    return any(pattern.match(h.strip()) for h in headings(path))


def _has_title(path: Path, title: str) -> bool:
    want = _plain(title)
    return bool(want) and any(_plain(t).startswith(want) or slug(h) == want
                              for h in headings(path, leads=True)
                              for t in (h, re.sub(r"\A(?:§\s*)?\d+(?:\.\d+)*\.?\s+", "", h)))


def _resolve(root: Path, citing: Path, ref: str) -> Path | None:
    """The file a reference names: relative to the citing file, else to the repository's
    root, else (a bare name) to ``docs/``."""
    candidates = [citing.parent / ref, root / ref]
    if "/" not in ref:
        candidates.append(root / "docs" / ref)
    for c in candidates:
        if c.is_file():
            return c.resolve()
    return None


def _section_problem(target: Path, after: str) -> str | None:
    """What is wrong with the section cited right after a path (None: nothing or fine)."""
    m = _ANCHOR.match(after)
    if m:
        return None if m.group(1) in anchors(target) else f"no anchor #{m.group(1)}"
    m = _NUMBER.match(after)
    if m:
        return None if _has_number(target, m.group(1)) else f"no section §{m.group(1)}"
    m = _TITLE.match(after)
    if m:
        title = m.group(1) or m.group(2)
        return None if _has_title(target, title) else f"no section {title!r}"
    return None


def _line(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


# --------------------------------------------------------------------------- the checks
def reference_problems(root: Path) -> list[str]:
    """Every reference to a document in the scanned files that does not resolve."""
    problems = []
    for path in _files(root):
        text = path.read_text(encoding="utf-8", errors="replace")
        where = path.relative_to(root)
        for m in _PATH.finditer(text):
            ref = m.group(1)
            if Path(ref).name in NOT_DOCUMENTS or text[max(0, m.start() - 3):m.start()] == "://":
                continue
            if ref.startswith("/"):
                problems.append(f"{where}:{_line(text, m.start())}: {ref} is outside the "
                                f"repository")
                continue
            target = _resolve(root, path, ref)
            if target is None:
                problems.append(f"{where}:{_line(text, m.start())}: {ref} is not in the "
                                f"repository")
                continue
            issue = _section_problem(target, text[m.end():m.end() + 200])
            if issue:
                problems.append(f"{where}:{_line(text, m.start())}: {ref}: {issue}")
        readme = root / "README.md"
        for m in _README.finditer(text):
            after = text[m.end():m.end() + 200]
            if not (_TITLE.match(after) or _NUMBER.match(after)):
                continue
            if not readme.is_file():
                problems.append(f"{where}:{_line(text, m.start())}: README.md is missing")
                continue
            issue = _section_problem(readme, after)
            if issue:
                problems.append(f"{where}:{_line(text, m.start())}: README: {issue}")
    return problems


def link_problems(root: Path) -> list[str]:
    """Every relative link (and image) of README.md and docs/**/*.md that does not resolve."""
    pages = [root / "README.md"] + sorted((root / "docs").rglob("*.md"))
    problems = []
    for page in pages:
        if not page.is_file():
            continue
        lines, fenced = page.read_text(encoding="utf-8").splitlines(), False
        for number, line in enumerate(lines, 1):
            if _FENCE.match(line):
                fenced = not fenced
            if fenced:
                continue
            for m in list(_LINK.finditer(line)) + list(_IMAGE.finditer(line)):
                href = m.group(1)
                if re.match(r"\A[a-z][a-z0-9+.-]*:", href):       # http:, mailto:, …
                    continue
                file_part, _, anchor = href.partition("#")
                target = (page.parent / file_part).resolve() if file_part else page
                where = f"{page.relative_to(root)}:{number}"
                if not target.exists():
                    problems.append(f"{where}: link {href} does not resolve")
                elif anchor and target.suffix == ".md" and anchor not in anchors(target):
                    problems.append(f"{where}: link {href}: no anchor #{anchor}")
    return problems


def index_problems(root: Path) -> list[str]:
    """Documents under docs/ that docs/index.md does not link."""
    index = root / "docs" / "index.md"
    if not index.is_file():
        return ["docs/index.md is missing"]
    linked = {(index.parent / m.group(1).partition("#")[0]).resolve()
              for m in _LINK.finditer(index.read_text(encoding="utf-8"))}
    return [f"docs/index.md does not list {p.relative_to(root)}"
            for p in sorted((root / "docs").rglob("*.md"))
            if p != index and p.resolve() not in linked]


def readme_problems(root: Path) -> list[str]:
    n = len((root / "README.md").read_text(encoding="utf-8").splitlines())
    return [] if n <= README_LIMIT else [f"README.md has {n} lines (at most {README_LIMIT})"]


# --------------------------------------------------------------------------- the tests
def test_every_cited_document_and_section_is_in_the_repository():
    problems = reference_problems(ROOT)
    assert not problems, "\n".join(problems)


def test_every_relative_link_of_the_docs_resolves():
    problems = link_problems(ROOT)
    assert not problems, "\n".join(problems)


def test_the_readme_is_short():
    assert not readme_problems(ROOT), readme_problems(ROOT)


def test_the_index_lists_every_document():
    problems = index_problems(ROOT)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("heading, anchor", [
    ("`flexarm bag export`: a bag as CSV tables", "flexarm-bag-export-a-bag-as-csv-tables"),
    ("3. Kinematics of a material point", "3-kinematics-of-a-material-point"),
    ("Performance (measured: `python bench/bench_ladder.py`)",
     "performance-measured-python-benchbench_ladderpy"),
    ("Rung auto: the model and the step for a tolerance",
     "rung-auto-the-model-and-the-step-for-a-tolerance"),
])
def test_anchors_are_githubs(heading, anchor):
    assert slug(heading) == anchor


def test_the_checks_find_what_is_broken(tmp_path):
    """The same checks on a small tree with one defect of each kind report each."""
    (tmp_path / "docs" / "decisions").mkdir(parents=True)
    (tmp_path / "flexarm_ros").mkdir()
    (tmp_path / "docs" / "physics.md").write_text(
        "# Physics\n\n## 1. Coordinates\n\n### 1.1 Joints\n\n## 2. Contact with a wall\n")
    (tmp_path / "docs" / "decisions" / "0003-a.md").write_text("# 0003 — A\n")
    good = ("See docs/physics.md §1.1, docs/physics.md, *Contact with a wall* and "
            "[the record](decisions/0003-a.md) and [contact](physics.md#2-contact-with-a-wall).\n")
    (tmp_path / "docs" / "index.md").write_text(
        "# Index\n\n- [physics](physics.md)\n- [a](decisions/0003-a.md)\n" + good)
    (tmp_path / "README.md").write_text("# t\n\n## Start-up\n\n" + good.replace(
        "(decisions/", "(docs/decisions/").replace("(physics.md", "(docs/physics.md"))
    (tmp_path / "flexarm_ros" / "m.py").write_text(
        '"""Equations (docs/physics.md §2; README "Start-up")."""\n')
    assert reference_problems(tmp_path) == []
    assert link_problems(tmp_path) == []
    assert index_problems(tmp_path) == []
    assert readme_problems(tmp_path) == []

    (tmp_path / "flexarm_ros" / "m.py").write_text(
        '"""Equations (PHYSICS.md; /work/shared/design/SEEDS.md; docs/physics.md §4; docs/physics.md, *Sensors*;\n'
        'README "Roadmap")."""\n')
    (tmp_path / "docs" / "extra.md").write_text(
        "# Extra\n\n[gone](design_notes.md) [bad anchor](physics.md#9-nothing)\n")
    (tmp_path / "README.md").write_text("\n" * (README_LIMIT + 1))
    refs = "\n".join(reference_problems(tmp_path))
    assert "PHYSICS.md is not in the repository" in refs
    assert "/work/shared/design/SEEDS.md is outside the repository" in refs
    assert "no section §4" in refs
    assert "no section 'Sensors'" in refs
    assert "README: no section 'Roadmap'" in refs
    links = "\n".join(link_problems(tmp_path))
    assert "design_notes.md does not resolve" in links and "no anchor #9-nothing" in links
    assert index_problems(tmp_path) == ["docs/index.md does not list docs/extra.md"]
    assert readme_problems(tmp_path)
