"""Where the packages of the distribution live (the metadata is in pyproject.toml).

The design card keeps its folders at the top of the repository (``schemas/``, ``nodes/``,
``flows/``, ...), while users import them under one name that cannot shadow other libraries
(``spectralize.nodes``, not ``nodes``). pyproject.toml alone cannot map found packages under a
prefix, so this file finds every package of each room and maps it: a new sub-package needs only
its ``__init__.py``, never an edit here (``tests/test_packaging.py`` checks that no folder of
Python files lacks one).
"""

from setuptools import find_packages, setup

# The rooms, in the one-way order of their imports (checked by import-linter).
ROOMS = ("schemas", "store", "engine", "nodes", "datasets", "flows")

package_dir = {"spectralize": "spectralize"}
packages = ["spectralize"]
for room in ROOMS:
    package_dir[f"spectralize.{room}"] = room
    packages.append(f"spectralize.{room}")
    packages.extend(f"spectralize.{room}.{name}" for name in find_packages(room))

setup(package_dir=package_dir, packages=packages)
