"""Every example in the product's docstrings runs and shows what it says (``doctest``)."""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _modules_with_examples() -> list[str]:
    names = []
    for top in ("seif_gym", "agents"):
        for path in sorted((ROOT / top).rglob("*.py")):
            if path.name == "__main__.py" or ">>>" not in path.read_text(encoding="utf-8"):
                continue
            parts = path.relative_to(ROOT).with_suffix("").parts
            names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


MODULES = _modules_with_examples()


def test_the_product_has_examples():
    assert "agents.loading" in MODULES and "seif_gym.slam.association" in MODULES and len(MODULES) > 15


@pytest.mark.slow  # the examples build envs and load policies: about 45 s in all
@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    pytest.importorskip("stable_baselines3", reason="the agents' examples need the train extra")
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed (run doctest on it)"
