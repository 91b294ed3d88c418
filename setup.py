"""The package list, found rather than listed: every folder of the checkout with an __init__.py is a subpackage of
the one import package `naocal` (pyproject.toml holds everything else). So adding a robot kind (kinds/<name>/) or
an effect module is adding files: nothing to register here. Data files (a `data/` folder beside a package's
modules) travel with their package."""

from pathlib import Path

from setuptools import find_packages, setup

ROOT = Path(__file__).resolve().parent
FOLDERS = ("agent", "backends", "body", "kinds", "sim", "solver", "tools")  # the top-level folders naocal maps

packages = ["naocal"] + [f"naocal.{folder}" for folder in FOLDERS]
packages += [f"naocal.{folder}.{sub}" for folder in FOLDERS for sub in find_packages(str(ROOT / folder))]
package_dir = {"naocal": "naocal", **{f"naocal.{folder}": folder for folder in FOLDERS}}
package_data = {package: ["data/*"] for package in packages
                if (ROOT / package_dir.get(package, package.replace("naocal.", "", 1).replace(".", "/")) / "data").is_dir()}

setup(packages=packages, package_dir=package_dir, package_data=package_data)
