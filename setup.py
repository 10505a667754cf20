"""Which packages the distribution holds: found, not listed (the rest is in pyproject.toml).

Every folder of the ``mcdenoise`` tree is a package, the data folders included (PEP 420
namespace packages such as ``mcdenoise/models/weights``, whose files pyproject.toml's
package-data takes whole), and ``cli/`` is the package ``mcdenoise_cli``. A list kept by hand
left out ``mcdenoise.ao``: an installed wheel (not the editable install ``make`` uses) could
not load its methods (issue 33, item 8). ``tests/test_packaging.py`` checks the list against
the folders, ``make wheel-check`` an installed wheel.
"""

from __future__ import annotations

import os

from setuptools import find_namespace_packages, setup

ROOT = os.path.dirname(os.path.abspath(__file__))


def packages() -> list[str]:
    """``mcdenoise`` and every folder below it (bytecode caches excepted), and ``mcdenoise_cli``."""
    found = find_namespace_packages(
        where=ROOT, include=["mcdenoise", "mcdenoise.*"], exclude=["*__pycache__*"]
    )
    return [*sorted(found), "mcdenoise_cli"]


if __name__ == "__main__":  # how setuptools runs it
    setup(packages=packages())
