"""Every results table of the README and the docs is what benchmarks/report.py renders from the JSON."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _report():
    spec = importlib.util.spec_from_file_location("report", ROOT / "benchmarks" / "report.py")
    report = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(report)
    return report


def test_every_page_is_scanned():
    report = _report()
    names = {path.relative_to(ROOT).as_posix() for path in report.pages()}
    assert "README.md" in names
    assert names >= {p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md")}


def test_tables_match_their_json():
    report = _report()
    assert report.check() == [], "run python benchmarks/report.py"


def test_every_renderer_is_used_and_every_block_has_one():
    report = _report()
    used = set()
    for path in report.pages():
        used |= set(report.OPEN.findall(path.read_text()))
    assert used <= set(report.TABLES)
    assert set(report.TABLES) <= used, "a renderer no page uses"


def test_a_block_without_a_renderer_is_an_error():
    report = _report()
    with pytest.raises(report.ReportError, match="docs/x.md.*no renderer for table 'nothing'"):
        report.rewrite("<!-- table:nothing -->\n<!-- /table:nothing -->\n", "docs/x.md")


def test_a_changed_figure_is_found_and_the_file_named(tmp_path):
    report = _report()
    page = tmp_path / "page.md"
    text = (ROOT / "README.md").read_text()
    page.write_text(text.replace("| duffing | bandlimited |", "| duffing | bandlimited | 1 |", 1))
    problems = report.check([page])
    assert len(problems) == 1 and problems[0].startswith(str(page))
