"""The README's results tables are what benchmarks/report.py renders from the JSON."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readme_tables_match_their_json():
    spec = importlib.util.spec_from_file_location("report", ROOT / "benchmarks" / "report.py")
    report = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(report)
    text = (ROOT / "README.md").read_text()
    assert report.rewrite(text) == text, "run python benchmarks/report.py"
