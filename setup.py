"""Package list for setuptools (everything else is in pyproject.toml).

The subpackages of ``ngcontact/`` are discovered automatically; the bundled scenes live in the
top-level ``cases/`` directory of the repository and are shipped as the subpackage ``ngcontact.cases``.
pyproject.toml alone cannot combine automatic discovery with such a mapped directory.
"""
from setuptools import find_packages, setup

setup(packages=find_packages(include=["ngcontact", "ngcontact.*"]) + ["ngcontact.cases"],
      package_dir={"ngcontact.cases": "cases"})
