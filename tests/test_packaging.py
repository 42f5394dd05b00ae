"""The robot-side install's pins (constraints/robot.txt) against pyproject.toml."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parent.parent


def _pins() -> dict[str, Version]:
    pins = {}
    for line in (ROOT / "constraints" / "robot.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints/robot.txt: {line!r} is not pinned with =="
            pins[canonicalize_name(name)] = Version(version)
    return pins


def test_every_robot_dependency_is_pinned_within_its_range():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    pins = _pins()  # the base install, the OAK's extra and the band refinement's
    extras = project["optional-dependencies"]
    for spec in project["dependencies"] + extras["oak"] + extras["band"]:
        req = Requirement(spec)
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} has no pin in constraints/robot.txt"
        assert req.specifier.contains(pins[name], prereleases=True), \
            f"{req.name}=={pins[name]} is outside pyproject's {req.specifier}"


def test_the_pins_hold_no_training_packages():
    assert not {"torch", "onnx", "tqdm", "matplotlib", "ray"} & set(_pins())


def test_every_package_folder_is_installed_under_edge_depth():
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {"edge_depth": "edge", **setuptools["package-dir"]}
    assert folders == {"edge_depth": "edge", "edge_depth.calibration": "calibration",
                       "edge_depth.tools": "tools"}
    expected = set()
    for name, folder in folders.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            sub = init.parent.relative_to(ROOT / folder).parts
            if not any(name + "." + p in folders for p in sub[:1]):
                expected.add(".".join((name,) + sub))
    data_only = {"edge_depth.models", "edge_depth.models.default"}  # the shipped model
    assert set(setuptools["packages"]) == expected | data_only
    assert not any((ROOT / "edge" / p.split(".", 1)[1].replace(".", "/") / "__init__.py").exists()
                   for p in data_only)
