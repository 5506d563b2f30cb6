"""docs/what_we_tested.md cannot drift from the tests: every test it names exists, and it names every fault test.

The page's tables end with a column of test ids (``tests/PATH.py::test_name``). Here each id must name
a test function defined in that file (parametrized or not) that is not skipped unconditionally, every
row must name at least one, and every test function of the fault-tolerance and bad-input test files
(:data:`FAULT_FILES`) must be named on the page: a new fault test without a row, or a row whose test was
renamed or removed, fails here.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "what_we_tested.md"
#: The test files whose every test is a fault or a bad input the page must list.
FAULT_FILES = (
    "tests/agents/test_resume.py",
    "tests/agents/test_resume_runs.py",
    "tests/agents/test_ray_faults.py",
    "tests/agents/test_bad_input_cli.py",
    "tests/slam/test_bad_input_filters.py",
    "tests/env/test_bad_input.py",
    "tests/env/test_vector_bad_input.py",
    "tests/datasets/test_bad_input_data.py",
    "tests/datasets/test_victoria_park_bad_input.py",
)
TEST_ID = re.compile(r"`(tests/[\w/]+\.py)::(test_\w+)`")


def _rows() -> list[tuple[str, list[tuple[str, str]]]]:
    """Each table row of the page: its first cell and the test ids of its last cell."""
    rows = []
    for line in PAGE.read_text(encoding="utf-8").splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")] if line.startswith("|") else []
        if len(cells) < 2 or set(cells[0]) <= set("-: ") or cells[-1] == "Tests":
            continue  # not a row, a separator, or a header
        rows.append((cells[0], TEST_ID.findall(cells[-1])))
    return rows


def _tests(path: str) -> dict[str, ast.FunctionDef]:
    """The module-level test functions of ``path``, by name."""
    tree = ast.parse((ROOT / path).read_text(encoding="utf-8"))
    return {
        node.name: node for node in tree.body if isinstance(node, ast.FunctionDef) and node.name.startswith("test_")
    }


def _skipped(function: ast.FunctionDef) -> bool:
    """Whether ``function`` carries an unconditional ``pytest.mark.skip`` (a ``skipif`` is a condition)."""
    for decorator in function.decorator_list:
        target = decorator.func if isinstance(decorator, ast.Call) else decorator
        if isinstance(target, ast.Attribute) and target.attr == "skip":
            return True
    return False


def test_the_page_has_rows_and_every_row_names_a_test():
    rows = _rows()
    assert len(rows) >= 30
    assert [label for label, ids in rows if not ids] == []


def test_every_test_the_page_names_exists_and_runs():
    named = {test for _, ids in _rows() for test in ids}
    for path, name in sorted(named):
        assert (ROOT / path).is_file(), f"{path} does not exist"
        functions = _tests(path)
        assert name in functions, f"{path}::{name} is named on the page but not defined"
        assert not _skipped(functions[name]), f"{path}::{name} is skipped"


@pytest.mark.parametrize("path", FAULT_FILES)
def test_every_fault_test_is_on_the_page(path):
    named = {name for _, ids in _rows() for file, name in ids if file == path}
    missing = sorted(set(_tests(path)) - named)
    assert missing == [], f"docs/what_we_tested.md does not name {path}'s {missing}"


def test_a_drifted_page_would_fail():
    """The checks can fail: a renamed test and an unlisted one are both caught."""
    ids = TEST_ID.findall("`tests/env/test_bad_input.py::test_no_such_test`")
    assert ids and ids[0][1] not in _tests(ids[0][0])
    everything = set(_tests("tests/env/test_bad_input.py"))
    assert everything - {"test_num_landmarks_bound"} != everything
