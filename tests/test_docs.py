"""The documents hold together: every figure README.md states is one docs/BENCHMARKS.md holds,
every file a document names exists, and every import a document shows resolves."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

ROOT = Path(__file__).parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]  # not the dated journal
# A figure: a decimal number, or a whole number with its unit ("13 min", "25 %", "2 of 9").
FIGURE = re.compile(
    r"(?<![\w.])(?P<num>\d+\.\d+)(?![\w.])"
    r"|(?<![\w.])\d+ ?(?:ms|s|min|MB|GB|%|x)(?!\w)|(?<![\w.])\d+ of \d+"
)
VERSION = re.compile(r"(?:Python|PyTorch|torch|ray|Ray) *[\d.]+\+?|[<>=]=\s*[\d.]+")  # not figures


def prose(text: str) -> str:
    """The text outside code blocks, white space folded."""
    return " ".join(re.sub(r"```.*?```", " ", text, flags=re.S).split())


def readme_figures_missing(readme: str, benchmarks: str) -> list[str]:
    """The figures of ``readme`` that ``benchmarks`` does not hold (decimals as numbers, whole
    numbers with their unit)."""
    held = " ".join(benchmarks.split())
    numbers = set(re.findall(r"(?<![\w.])\d+\.\d+(?![\w.])", held))
    missing = []
    for match in FIGURE.finditer(VERSION.sub(" ", prose(readme))):
        figure = match.group(0)
        found = figure in numbers if match.group("num") else figure in held
        if not found:
            missing.append(figure)
    return sorted(set(missing))


def test_every_figure_the_readme_states_is_in_benchmarks():
    readme = (ROOT / "README.md").read_text()
    benchmarks = (ROOT / "docs" / "BENCHMARKS.md").read_text()
    assert readme_figures_missing(readme, benchmarks) == []


def test_the_figure_check_can_fail():
    bench = "| model | 0.337 | 13 min 29 s | lost 2 of 9 | 25 % lower |"
    assert readme_figures_missing("RMSE 0.337, 13 min, 2 of 9, 25 % less", bench) == []
    assert readme_figures_missing("RMSE 0.338 in 14 min, 3 of 9, 26 %, on Python 3.10", bench) == [
        "0.338", "14 min", "26 %", "3 of 9",
    ]  # fmt: skip
    assert readme_figures_missing("```\n0.999\n```", bench) == []  # code is not a claim


def test_every_file_the_docs_name_exists():
    tracked = [p.relative_to(ROOT).as_posix() for p in ROOT.rglob("*.py") if ".git" not in p.parts]
    named = re.compile(r"`([A-Za-z0-9_][A-Za-z0-9_./-]*\.py)`")
    missing = [
        f"{doc.name}:{n}: {name}"
        for doc in DOCS
        for n, line in enumerate(doc.read_text().splitlines(), 1)
        for name in named.findall(line)
        if not any(f == name or f.endswith("/" + name) for f in tracked)
    ]
    assert missing == []


def test_every_import_the_docs_show_resolves():
    shown = re.compile(r"^\s*from (slungload[\w.]*) import ([\w, ]+)$", re.M)
    failed = []
    for doc in DOCS:
        for module, names in shown.findall(doc.read_text()):
            loaded = importlib.import_module(module)
            failed += [f"{doc.name}: {module}.{name.strip()}" for name in names.split(",")
                       if name.strip() and not hasattr(loaded, name.strip())]  # fmt: skip
    assert failed == []


def test_every_section_the_docs_cite_is_there():
    # `docs/BENCHMARKS.md`, "Name": a heading of that document holds the name
    cited = re.compile(r"`(docs/[\w/.-]+\.md)`,\s+\"([^\"]+)\"")
    headings = {}
    missing = []
    for doc in DOCS:
        for target, name in cited.findall(" ".join(doc.read_text().split())):
            if target not in headings:
                lines = (ROOT / target).read_text().lower().splitlines()
                headings[target] = [line.lstrip("#").strip() for line in lines if line[:1] == "#"]
            if not any(name.lower() in h for h in headings[target]):
                missing.append(f"{doc.name}: {target}, {name!r}")
    assert missing == []
