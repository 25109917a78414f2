"""Every package folder on disk is declared in pyproject.toml (one namespace: arcsem.*)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

ROOT = Path(__file__).resolve().parent.parent
SETUPTOOLS = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
PACKAGE_DIR = SETUPTOOLS["package-dir"]


def packages_on_disk() -> set[str]:
    """Dotted names of every folder with ``__init__.py`` under the mapped top-level folders."""
    names = set()
    for package, folder in PACKAGE_DIR.items():
        base = ROOT / folder
        for init in base.rglob("__init__.py"):
            rel = init.parent.relative_to(base)
            if "__pycache__" in rel.parts:
                continue
            names.add(".".join([package, *rel.parts]))
    return names


def test_package_dir_mapping():
    assert PACKAGE_DIR == {"arcsem": "arcsem", "arcsem.backbones": "backbones", "arcsem.losses": "losses",
                           "arcsem.conf": "conf"}


def test_every_package_folder_is_listed():
    listed = set(SETUPTOOLS["packages"])
    missing = sorted(packages_on_disk() - listed)
    assert not missing, f"add to [tool.setuptools] packages in pyproject.toml: {missing}"


def test_every_listed_package_exists():
    stale = sorted(set(SETUPTOOLS["packages"]) - packages_on_disk())
    assert not stale, f"listed in pyproject.toml but no folder with __init__.py: {stale}"


@pytest.mark.parametrize("package", sorted(PACKAGE_DIR))
def test_installed_namespace_points_at_the_checkout(package):
    spec = importlib.util.find_spec(package)
    assert spec is not None and spec.origin is not None
    assert Path(spec.origin).resolve() == (ROOT / PACKAGE_DIR[package] / "__init__.py").resolve()


def test_yaml_shipped_as_package_data():
    assert "**/*.yaml" in SETUPTOOLS["package-data"]["arcsem.conf"]
    assert any((ROOT / "conf").rglob("*.yaml"))
