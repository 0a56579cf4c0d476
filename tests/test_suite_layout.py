"""The test suite's own layout: test modules never import each other (what several share lives in a helper module
such as ``helpers.py`` or in a ``conftest.py`` fixture), and no file is named after the round that wrote it."""

from __future__ import annotations

import ast
import re
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def _imported_modules(path: Path) -> list[str]:
    """Every module name ``path`` imports (``import a.b`` -> ``a.b``; ``from a.b import c`` -> ``a.b`` and
    ``a.b.c``), at any depth (imports inside functions count too)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names += [node.module, *(f"{node.module}.{alias.name}" for alias in node.names)]
    return names


def _test_module_imports(path: Path) -> list[str]:
    """The test modules (``test_*``, bare or under ``tests.``) that ``path`` imports."""
    return sorted({name for name in _imported_modules(path)
                   if any(part.startswith("test_") for part in name.split(".")[:2])})


def test_test_modules_never_import_each_other():
    offenders = {str(path.relative_to(TESTS)): found for path in sorted(TESTS.rglob("*.py"))
                 if (found := _test_module_imports(path))}
    assert not offenders, f"test modules import other test modules (move what they share to a helper module " \
                          f"or a conftest fixture): {offenders}"


def test_the_import_check_sees_every_spelling(tmp_path):
    src = tmp_path / "test_x.py"
    src.write_text("import os\nfrom helpers import needs_gl\nfrom tests.helpers import demo_scene\n"
                   "from test_onnx import SHIPPED\nimport tests.test_cli\n\ndef f():\n"
                   "    from tests.test_editor_browser import wait_for\n")
    assert _test_module_imports(src) == ["test_onnx", "test_onnx.SHIPPED", "tests.test_cli",
                                         "tests.test_editor_browser", "tests.test_editor_browser.wait_for"]


def test_no_file_is_named_after_a_round():
    rounds = [str(p.relative_to(TESTS)) for p in TESTS.rglob("*.py") if re.search(r"round\d", p.stem)]
    assert not rounds, f"name these test files after what they check: {rounds}"
