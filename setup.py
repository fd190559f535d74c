"""Package discovery for the folder layout: capture/, stereo/, dataset/ -> staticdepth.<name>.

Everything else (metadata, dependencies, entry points) lives in pyproject.toml.
"""
from setuptools import find_packages, setup

MAPPED = ("capture", "stereo", "dataset")

packages = ["staticdepth"] + [f"staticdepth.{p}" for p in find_packages("staticdepth")]
package_dir = {"staticdepth": "staticdepth"}
for folder in MAPPED:
    packages += [f"staticdepth.{folder}"] + [f"staticdepth.{folder}.{p}" for p in find_packages(folder)]
    package_dir[f"staticdepth.{folder}"] = folder

setup(packages=packages, package_dir=package_dir, package_data={"staticdepth": ["data/*"]})
