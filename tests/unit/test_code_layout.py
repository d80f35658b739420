"""The code's layout rules (issue 36, CONTRIBUTING.md): no test imports the benchmarks (what
both need lives in tests/support, which the benchmarks import; a test of a benchmark runs
its documented command as a process), and no Python module is over 500 lines."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MAX_LINES = 500


def imported_modules(path: Path) -> set[str]:
    """The absolute module names ``path`` imports (relative imports are the tests' own)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def test_no_test_module_imports_the_benchmarks():
    offenders = sorted(
        str(path.relative_to(ROOT)) for path in ROOT.joinpath("tests").rglob("*.py")
        if any(name == "benchmarks" or name.startswith("benchmarks.")
               for name in imported_modules(path)))
    assert offenders == [], f"move what they share into tests/support: {offenders}"


def test_the_import_scan_sees_every_form(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("import benchmarks.fleet as f\nfrom benchmarks import daemon\n"
                     "def late():\n    from benchmarks.reliability.soak import soak\n"
                     "from . import sibling\n")
    assert imported_modules(probe) == {"benchmarks.fleet", "benchmarks",
                                       "benchmarks.reliability.soak"}


def test_no_module_is_over_500_lines():
    long = sorted(
        (str(path.relative_to(ROOT)), n)
        for folder in ("service", "sitl", "benchmarks", "tests")
        for path in ROOT.joinpath(folder).rglob("*.py")
        if (n := len(path.read_text().splitlines())) > MAX_LINES)
    assert long == [], f"split these by concept: {long}"
