"""The package list of the build; everything else is in pyproject.toml.

The packages are found rather than listed, so that none is left out of the sdist and the wheel: every
package under stereogeo_cli/ (a folder without ``__init__.py`` too), and ``stereogeo_cli.models``, which is
the repository's models/ folder (pyproject.toml maps it and names the files it ships). pyproject.toml's own
``packages.find`` cannot add that one: it only finds folders under the name they have in the checkout.
"""

from setuptools import find_namespace_packages, setup

found = find_namespace_packages(include=["stereogeo_cli", "stereogeo_cli.*"], exclude=["*.__pycache__"])
setup(packages=sorted({*found, "stereogeo_cli.models"}))
