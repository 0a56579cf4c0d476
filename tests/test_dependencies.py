"""Every third-party module the code or the tests import comes with the install the README documents:
``pip install -e ".[dev]"`` installs its distribution (declared in ``dependencies`` or an extra of
``pyproject.toml``, or required by one that is). A test that imports an undeclared module would skip (an
``importorskip``) or fail on a fresh machine while passing on one where it was installed by hand."""

from __future__ import annotations

import ast
import re
import sys
from importlib.metadata import PackageNotFoundError, packages_distributions, requires
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SOURCES = ("smplik", "workflows", "shape_inversion", "tests", "benchmarks", "docs")


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def requirement_name(requirement: str) -> str:
    return canonical(re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", requirement).group(1))


def declared() -> set[str]:
    """Distributions named in pyproject's dependencies and every extra."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib  # type: ignore[no-redef]
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    names = {requirement_name(r) for r in project["dependencies"]}
    for extra in project["optional-dependencies"].values():
        names |= {requirement_name(r) for r in extra if not r.startswith(project["name"])}
    return names


def installed_with(roots: set[str]) -> set[str]:
    """``roots`` and every distribution they require (their own extras left out), as installed here."""
    seen, todo = set(), list(roots)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        try:
            reqs = requires(name) or []
        except PackageNotFoundError:
            continue
        todo += [requirement_name(r) for r in reqs if "extra ==" not in r.replace('"', "").replace("'", "")]
    return seen


def imported_modules() -> dict[str, Path]:
    """Top-level module -> first file importing it, over the repository's Python files."""
    files = [path for folder in SOURCES for path in sorted((REPO / folder).rglob("*.py"))]
    local = {p.stem for p in REPO.iterdir()} | {p.stem for p in files}  # scripts import their neighbours
    found: dict[str, Path] = {}
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            elif (isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "importorskip"
                  and node.args and isinstance(node.args[0], ast.Constant)):
                names = [node.args[0].value]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top not in local and top != "__future__":
                    found.setdefault(top, path.relative_to(REPO))
    return found


def test_every_imported_package_is_installed_by_the_documented_install():
    provided = installed_with(declared())
    owners = packages_distributions()
    missing = []
    for module, where in sorted(imported_modules().items()):
        if module == "tomli":  # the Python 3.10 fallback of this test (tomllib is in 3.11's standard library)
            continue
        dists = {canonical(d) for d in owners.get(module, [])}
        if not dists & provided:
            missing.append(f"{module} (imported by {where}; distribution {sorted(dists) or 'not installed'})")
    assert not missing, "not in pyproject's dependencies or extras: " + "; ".join(missing)
