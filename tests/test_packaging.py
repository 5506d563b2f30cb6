"""The built wheel ships what a non-editable install needs: the policies, their configs, every module."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


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
    for module in (ROOT / "seif_gym").rglob("*.py"):
        assert module.relative_to(ROOT).as_posix() in names
    # PEP 561 markers: type checkers read the packages' own annotations
    assert {"seif_gym/py.typed", "agents/py.typed"} <= names
    metadata = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    requirements = [line for line in metadata.splitlines() if line.startswith("Requires-Dist:")]
    for package in ("gymnasium", "numpy", "scipy", "numba", "matplotlib", "stable-baselines3", "pyyaml", "pillow"):
        assert any(package in line.lower() for line in requirements), package
