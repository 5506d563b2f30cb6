"""The built wheel ships what a non-editable install needs: the policies, their configs, every module."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_wheel_ships_policies_configs_and_declares_its_imports(tmp_path):
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            str(ROOT),
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
        ],
        check=True,
        capture_output=True,
    )
    (wheel,) = tmp_path.glob("seif_gym-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for shipped in (ROOT / "agents" / "policies").glob("*.zip"):
        assert f"agents/policies/{shipped.name}" in names
    for stats in (ROOT / "agents" / "policies").glob("*/vecnormalize.pkl"):  # a policy's normalisation
        assert stats.relative_to(ROOT).as_posix() in names
    for record in (ROOT / "agents" / "policies").glob("*/command.txt"):  # the command that trained it
        assert record.relative_to(ROOT).as_posix() in names
    for config in (ROOT / "agents" / "hyperparams").glob("*.yml"):
        assert f"agents/hyperparams/{config.name}" in names
    assert "agents/policies/held_out.json" in names  # agents.list_pretrained's results
    for package in ("seif_gym", "agents"):
        for module in (ROOT / package).rglob("*.py"):
            assert module.relative_to(ROOT).as_posix() in names
    # the product alone: the lab, the tests and the research policies stay out of the wheel
    assert {name.split("/")[0] for name in names if not name.startswith("seif_gym-")} == {"seif_gym", "agents"}
    # a policy needs no optimizer state or value function to act: the shipped ones fit in 20 MB
    assert wheel.stat().st_size <= 20 * 1024 * 1024, wheel.stat().st_size
    # PEP 561 markers: type checkers read the packages' own annotations
    assert {"seif_gym/py.typed", "agents/py.typed"} <= names
    metadata = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    requirements = [line for line in metadata.splitlines() if line.startswith("Requires-Dist:")]
    for package in ("gymnasium", "numpy", "scipy", "numba", "matplotlib", "stable-baselines3", "pyyaml", "pillow"):
        assert any(package in line.lower() for line in requirements), package
