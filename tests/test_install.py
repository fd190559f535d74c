"""The folder layout installs as staticdepth.{capture,stereo,dataset}: normal and editable."""
import os
import subprocess
import sys
import zipfile

import pytest

from conftest import REPO

SUBPACKAGES = ("staticdepth.capture", "staticdepth.stereo", "staticdepth.dataset",
               "staticdepth.geometry")


def test_editable_install_maps_folders():
    import importlib

    for name, folder in (("staticdepth.capture", "capture"), ("staticdepth.stereo", "stereo"),
                         ("staticdepth.dataset", "dataset")):
        mod = importlib.import_module(name)
        assert os.path.dirname(mod.__file__) == str(REPO / folder)


def test_wheel_contains_mapped_packages_and_imports(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                        "-q", "-w", str(tmp_path / "wheel"), str(REPO)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.fail(f"wheel build failed: {r.stderr[-2000:]}")
    (whl,) = (tmp_path / "wheel").glob("staticdepth-*.whl")
    names = zipfile.ZipFile(whl).namelist()
    for pkg in SUBPACKAGES:
        assert pkg.replace(".", "/") + "/__init__.py" in names
    assert not any(n.startswith(("dataset/", "stereo/", "capture/", "tests/")) for n in names)
    target = tmp_path / "site"
    zipfile.ZipFile(whl).extractall(target)
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import staticdepth.dataset.h5, "
            "staticdepth.stereo, staticdepth.capture, staticdepth.cli; "
            "print(staticdepth.dataset.h5.__file__)")
    out = subprocess.run([sys.executable, "-c", code, str(target)], capture_output=True, text=True,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().startswith(str(target))
