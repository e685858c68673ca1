"""The layout rules of the project, checked over the source tree with ``ast``.

Ground (``fedtrack/``) <- ``local_filters`` <- ``fusion_center`` <- the application
(``deploy``, ``benchmarks``, ``experiments``, the CLI). ``sensors`` (simulation) may use
ground and ``local_filters``; no library package imports it.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# source folder -> import name in the installed distribution
PACKAGES = {
    "fedtrack": "fedtrack",
    "local_filters": "fedtrack.local_filters",
    "fusion_center": "fedtrack.fusion_center",
    "sensors": "fedtrack.sensors",
    "deploy": "fedtrack.deploy",
    "benchmarks": "fedtrack.benchmarks",
    "experiments": "fedtrack.experiments",
}
LIBRARY = ("fedtrack", "local_filters", "fusion_center")
APPLICATION = ("deploy", "benchmarks", "experiments")
CLI_ENTRY = "fedtrack.cli"
# what each group may import (besides itself)
ALLOWED = {
    "fedtrack": set(),
    "local_filters": {"fedtrack"},
    "fusion_center": {"fedtrack", "local_filters"},
    "sensors": {"fedtrack", "local_filters"},
    "deploy": set(PACKAGES),
    "benchmarks": set(PACKAGES),
    "experiments": set(PACKAGES),
}
MAX_MODULES = 12


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    top = PACKAGES[parts[0]].split(".")
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(top + parts[1:])


def source_files() -> list[Path]:
    return sorted(p for top in PACKAGES for p in (ROOT / top).rglob("*.py"))


def group_of(module: str) -> str | None:
    """The source folder a ``fedtrack...`` module lives in (None: not ours)."""
    parts = module.split(".")
    if parts[0] != "fedtrack":
        return None
    if len(parts) > 1:
        for folder, name in PACKAGES.items():
            if folder != "fedtrack" and parts[1] == name.split(".")[1]:
                return folder
    return "fedtrack"


def imports_of(path: Path) -> frozenset[str]:
    """Every module imported anywhere in the file (inside functions too), absolute names."""
    return _imports_of(path, path.read_text())


@functools.cache
def _imports_of(path: Path, text: str) -> frozenset[str]:
    """:func:`imports_of`, parsed once per file content (three rules walk every source file)."""
    tree = ast.parse(text, str(path))
    own = module_name(path)
    package = own if path.name == "__init__.py" else own.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            found.add(mod)
            found.update(f"{mod}.{a.name}" for a in node.names)
    return frozenset(found)


def our_modules() -> set[str]:
    return {module_name(p) for p in source_files()}


def import_graph() -> dict[str, set[str]]:
    mods = our_modules()
    graph: dict[str, set[str]] = {}
    for path in source_files():
        name = module_name(path)
        if name == CLI_ENTRY:
            continue
        graph[name] = {m for m in imports_of(path) if m in mods and m != name and m != CLI_ENTRY}
    return graph


def test_no_unnamespaced_imports_of_project_folders() -> None:
    bad = []
    for path in source_files() + sorted((ROOT / "tests").rglob("*.py")):
        for mod in imports_of(path) if path.parent.name != "tests" else _plain_imports(path):
            if mod.split(".")[0] in PACKAGES and mod.split(".")[0] != "fedtrack":
                bad.append(f"{path.relative_to(ROOT)}: {mod}")
    assert not bad, "import the folders by their fedtrack.* names: " + "; ".join(bad)


def _plain_imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            found.add(node.module)
    return found


def test_dependencies_point_one_way() -> None:
    bad = []
    for path in source_files():
        name = module_name(path)
        if name == CLI_ENTRY:
            continue
        mine = path.relative_to(ROOT).parts[0]
        for mod in imports_of(path):
            other = group_of(mod)
            if other is None or other == mine or mod == "fedtrack":
                continue
            if other not in ALLOWED[mine]:
                bad.append(f"{name} imports {mod} ({mine} -> {other})")
    assert not bad, "\n".join(bad)


def test_import_graph_has_no_cycle() -> None:
    graph = import_graph()
    # a module's import of a package means its __init__; treat as an edge too
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt):] + [nxt]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    assert state, "no modules found"


def test_library_folders_are_small_and_hold_no_reproductions() -> None:
    bad = []
    for top in ("fedtrack", "local_filters", "fusion_center", "sensors"):
        for folder in [ROOT / top, *[p for p in (ROOT / top).rglob("*") if p.is_dir() and p.name != "__pycache__"]]:
            modules = [p for p in folder.glob("*.py") if p.name != "__init__.py"]
            if len(modules) > MAX_MODULES:
                bad.append(f"{folder.relative_to(ROOT)} holds {len(modules)} modules")
            bad += [f"{p.relative_to(ROOT)} is a reproduction or plot module" for p in modules
                    if "reproduce" in p.stem or "plots" in p.stem]
    assert not bad, "\n".join(bad)


def test_rules_catch_a_violation(tmp_path: Path) -> None:
    """The checker sees an upward import, inside a function too."""
    fake = ROOT / "local_filters" / "_layout_probe.py"
    fake.write_text("def f():\n    from fedtrack.fusion_center import trackers\n")
    try:
        with pytest.raises(AssertionError, match="local_filters -> fusion_center"):
            test_dependencies_point_one_way()
    finally:
        fake.unlink()


def test_every_package_folder_is_installed() -> None:
    """Each folder with an ``__init__.py`` is listed in pyproject's ``packages``."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {module_name(p) for p in source_files() if p.name == "__init__.py"}
    assert found == listed, f"missing: {sorted(found - listed)}, stale: {sorted(listed - found)}"


MULTI_TARGET_SERVICES = ("fedtrack.fusion_center.mtt.service", "fedtrack.local_filters.mtt.service",
                         "fedtrack.fusion_center.mtt.picture_merge")


def test_multi_target_services_do_not_import_scipy_stats() -> None:
    """``scipy.stats`` adds about 20 MB to a process and its distributions cost about 60 us a call: the
    consistency monitor's F tail from it raised every region centre's RSS from 87 to 108 MB after import
    and its per-report cost (issue 27's load bars); what the services need is in ``scipy.special``.
    One fresh interpreter imports the services in turn, asked after each: an import only adds to
    ``sys.modules``, so the first service that answers True is one that imports it."""
    import subprocess
    import sys

    code = ("import importlib, sys\n"
            f"for name in {MULTI_TARGET_SERVICES!r}:\n"
            "    importlib.import_module(name)\n"
            "    print(name, 'scipy.stats' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    answers = dict(line.split() for line in out.stdout.splitlines())
    assert list(answers) == list(MULTI_TARGET_SERVICES), out.stdout
    importing = [name for name, answer in answers.items() if answer != "False"]
    assert not importing, f"{importing[0]} imports scipy.stats"
