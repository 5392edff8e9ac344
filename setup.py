"""Maps the top-level code folders onto the ``weldcell`` import namespace.

``sdk/`` -> ``weldcell.sdk``, ``hal/`` -> ``weldcell.hal``, ``plugins/`` -> ``weldcell.plugins``,
``testing/`` -> ``weldcell.testing``. Everything else lives in pyproject.toml.
"""

from setuptools import find_packages, setup

FOLDERS = {
    "weldcell.sdk": "sdk",
    "weldcell.hal": "hal",
    "weldcell.plugins": "plugins",
    "weldcell.testing": "testing",
}

packages = []
for prefix, folder in FOLDERS.items():
    packages.append(prefix)
    packages += [f"{prefix}.{sub}" for sub in find_packages(folder)]

setup(packages=packages, package_dir=dict(FOLDERS))
