"""What users look for: the license, type information, public names reachable as attributes."""

import os
import tomllib

from _paths import ROOT

import diffkin as dk


def test_license_and_typing_marker():
    with open(os.path.join(ROOT, "LICENSE")) as f:
        text = f.read()
    assert text.startswith("MIT License") and "diffkin developers" in text
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        project = tomllib.load(f)
    assert project["project"]["license"] == "MIT"
    assert "py.typed" in project["tool"]["setuptools"]["package-data"]["diffkin"]
    assert os.path.isfile(os.path.join(os.path.dirname(dk.__file__), "py.typed"))
    extras = project["project"]["optional-dependencies"]
    assert {"demo", "ik", "plot", "progress", "validate", "dev", "test"} <= set(extras)
    markers = " ".join(project["tool"]["pytest"]["ini_options"]["markers"])
    assert all(f"{name}:" in markers for name in ("unit", "validation", "integration", "slow"))


def test_public_names():
    assert dk.se3.vee is not None and "se3" in dk.__all__ and "se3" in dir(dk)
    assert all(callable(getattr(dk.robots, name)) for name in dk.robots.__all__)
    assert {"iiwa14", "panda", "planar", "urdf_path"} <= set(dk.robots.__all__)
