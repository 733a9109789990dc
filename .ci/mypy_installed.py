"""mypy on the package as pip installs it, `kernels/` and `training/` under `aquarium_warp` (pyproject's
[tool.setuptools.package-dir]): `python -m mypy` names modules by their folders, so it types every import
between the three folders as Any; here those imports are checked. The layout is staged as links in a
temporary folder, checked with pyproject's [tool.mypy] settings: `python .ci/mypy_installed.py`."""

import os
import subprocess
import sys
import tempfile

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def stage(folder: str) -> None:
    """Links the files and folders of each package's source folder into `folder`, at its import path."""
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        package_dirs = tomllib.load(f)["tool"]["setuptools"]["package-dir"]
    for package, source in sorted(package_dirs.items()):  # a package before its subpackages
        target = os.path.join(folder, *package.split("."))
        os.makedirs(target, exist_ok=True)
        for name in os.listdir(os.path.join(ROOT, source)):
            if name != "__pycache__" and not os.path.exists(os.path.join(target, name)):
                os.symlink(os.path.join(ROOT, source, name), os.path.join(target, name))


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as folder:
        stage(folder)
        config = ["--config-file", os.path.join(ROOT, "pyproject.toml")]
        cache = ["--cache-dir", os.path.join(ROOT, ".mypy_cache", "installed")]
        sys.exit(subprocess.call([sys.executable, "-m", "mypy", *config, *cache, "-p", "aquarium_warp"], cwd=folder))
