"""The README and docs/: short enough to read, no lab-notebook residue (issue numbers, clock times), every relative
link resolves inside the repository, every generated table is what its command writes, and the README states the
commands CI runs."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [README, *DOCS]
# The studies' index is written where the studies live; until that tree is in this checkout its links are exempt.
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)|<img\s[^>]*src=\"([^\"]+)\"")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def _ids(pages):
    return [str(p.relative_to(ROOT)) for p in pages]


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped except '-' and '_', spaces to '-'."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = FENCE.sub("", path.read_text())
    return {_slug(m.group(1)) for m in re.finditer(r"^#{1,6}\s+(.*)$", text, re.M)}


def test_readme_is_at_most_200_lines():
    assert len(README.read_text().splitlines()) <= 200


@pytest.mark.parametrize("page", PAGES, ids=_ids(PAGES))
def test_no_issue_numbers_or_clock_times(page):
    text = page.read_text()
    assert not re.findall(r"issue\s*#?\d+", text, re.I), "issue numbers belong in commit messages"
    times = re.findall(r"\b\d{1,2}:\d{2}(?::\d{2})?(?:\s*-\s*\d{1,2}:\d{2})?\s*(?:UTC|Z\b)", text)
    assert not times, f"clock times (one date and machine line per table is enough): {times}"


@pytest.mark.parametrize("page", PAGES, ids=_ids(PAGES))
def test_relative_links_resolve_inside_the_repository(page):
    text = FENCE.sub("", page.read_text())
    broken = []
    for m in LINK.finditer(text):
        target = m.group(1) or m.group(2)
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        path_part, _, anchor = target.partition("#")
        dest = (page.parent / path_part).resolve() if path_part else page
        rel = dest.relative_to(ROOT) if dest.is_relative_to(ROOT) else None
        if rel is None:
            broken.append(f"{target} (outside the repository)")
        elif not dest.exists():
            broken.append(f"{target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(f"{target} (no such heading)")
    assert not broken, broken


def test_readme_holds_the_ci_test_command():
    """.ci/run runs the README's test command: the same line, less pip's -q (CI keeps its log short)."""
    lines = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines()]
    command = next(ln for ln in lines if "pytest" in ln and not ln.startswith("#"))
    command = command.replace("pip install -q ", "pip install ")
    assert command in README.read_text()


@pytest.mark.parametrize("page", PAGES, ids=_ids(PAGES))
def test_generated_blocks_are_what_their_command_writes(page):
    from vswrist_gym.tools.table import regenerate

    text = page.read_text()
    if "<!-- BEGIN GENERATED:" not in text:
        pytest.skip("no generated blocks")
    assert regenerate(page) == text, \
        f"stale tables: run python -m vswrist_gym.tools.table --write {page.relative_to(ROOT)}"


def test_each_benchmark_states_its_command_and_one_date_and_machine():
    """A benchmark section with a table names the command that remakes it and says once when and where."""
    text = (ROOT / "docs" / "benchmarks.md").read_text()
    sections = re.split(r"^### ", text, flags=re.M)[1:]
    assert len(sections) >= 5
    for body in sections:
        title = body.splitlines()[0]
        has_table = re.search(r"^\|.*\|$", body, re.M) or "```text" in body or "GENERATED:" in body
        if not has_table:
            continue
        assert "```bash" in body, title
        dated = re.findall(r"^\d{4}-\d{2}-\d{2}, .*(?:machine|CPU)", body, re.M)
        assert len(dated) == 1, (title, dated)


def test_readme_verdict_is_the_main_job_table():
    """The README says both learned agents beat the best fixed stiffness only while the table says so."""
    bench = (ROOT / "docs" / "benchmarks.md").read_text()
    block = re.search(r"BEGIN GENERATED: compare-table \S+ -->\n(.*?)<!-- END", bench, re.S).group(1)
    verdicts = {m.group(1): m.group(2) for m in re.finditer(r"^- (PPO|SAC): (\S+)", block, re.M)}
    claimed = "both PPO and SAC beat the best fixed stiffness" in README.read_text()
    assert claimed == (verdicts.get("PPO") == verdicts.get("SAC") == "beats")
