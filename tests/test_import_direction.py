"""One direction of imports: the library (``seif_gym``) never imports the applications (``agents``)."""

from __future__ import annotations

import ast
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

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
    assert "seif_gym.evaluate" in modules and "seif_gym.metrics" in modules and len(modules) > 20
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
