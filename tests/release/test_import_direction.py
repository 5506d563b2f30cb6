"""One direction of imports: the library (``seif_gym``) never imports the applications (``agents``)."""

from __future__ import annotations

import ast
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import seif_gym

PACKAGE = Path(seif_gym.__file__).parent


def _modules() -> list[str]:
    names = ["seif_gym"]
    for info in pkgutil.walk_packages([str(PACKAGE)], prefix="seif_gym."):
        names.append(info.name)
    return sorted(names)


def test_no_module_of_seif_gym_imports_agents_statically():
    offending = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""] if node.level == 0 else []
            elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in (
                "import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant):  # fmt: skip
                names = [str(node.args[0].value)]
            else:
                continue
            offending += [f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {name}" for name in names
                          if name == "agents" or name.startswith("agents.")]  # fmt: skip
    assert not offending, offending


def test_importing_every_module_of_seif_gym_loads_no_agents():
    modules = _modules()
    assert "seif_gym.harness" in modules and "seif_gym.metrics" in modules and len(modules) > 20
    code = (
        "import importlib, sys\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module(name)\n"
        "loaded = sorted(m for m in sys.modules if m == 'agents' or m.startswith('agents.'))\n"
        "assert not loaded, loaded\n"
    )
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]


# -- the product never imports the lab; no module imports itself back -----------------------------------
ROOT = PACKAGE.parent
PRODUCT = ("seif_gym", "agents")


def _imports(path: Path, module: str) -> list[tuple[int, str]]:
    """Every module ``path`` (the module ``module``) imports, lazy ones inside functions included."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    # imports only a type checker runs (``if TYPE_CHECKING:``) make no circle at run time
    typing_only = {
        id(inner)
        for node in ast.walk(tree)
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
        for stmt in node.body
        for inner in ast.walk(stmt)
    }
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            # ``from a.b import c``: the submodule a.b.c where it is one, else a.b
            for alias in node.names:
                candidate = f"{base}.{alias.name}"
                found.append((node.lineno, candidate if _module_path(candidate) else base))
    return found


def _module_path(name: str) -> Path | None:
    path = ROOT.joinpath(*name.split("."))
    for candidate in (path.with_suffix(".py"), path / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _product_modules() -> dict[str, Path]:
    modules: dict[str, Path] = {}
    for top in PRODUCT:
        for path in sorted((ROOT / top).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            modules[name] = path
    return modules


def test_the_product_never_imports_research():
    offending = [
        f"{path.relative_to(ROOT)}:{line} {name}"
        for module, path in _product_modules().items()
        for line, name in _imports(path, module)
        if name == "research" or name.startswith("research.")
    ]
    assert not offending, offending


def test_no_import_circles_in_the_product_lazy_imports_included():
    modules = _product_modules()
    graph = {
        module: sorted({name for _, name in _imports(path, module) if name in modules and name != module})
        for module, path in modules.items()
    }
    # Tarjan's strongly connected components: a component of more than one module is a circle
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph[node]:
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    assert len(modules) > 60
    assert not circles, circles


@pytest.mark.slow
def test_importing_every_module_of_agents_loads_no_research():
    # a package's __main__ runs its command when imported: its imports are read statically above
    modules = [name for name in _product_modules() if name.startswith("agents") and not name.endswith("__main__")]
    code = (
        "import importlib, sys\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module(name)\n"
        "loaded = sorted(m for m in sys.modules if m == 'research' or m.startswith('research.'))\n"
        "assert not loaded, loaded\n"
    )
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600, cwd=ROOT
    )
    assert result.returncode == 0, result.stderr[-3000:]
