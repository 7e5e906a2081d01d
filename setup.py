"""The build step that puts the built-in viewer's bundle into the package.

Everything else about the package is declared in pyproject.toml. Building a
wheel (``pip install .``, ``pip wheel .``, or from the sdist) runs
``scripts/build-viewer.sh`` first, which bundles ``viewer/`` into
``xviz_server/viewer_static/``, the package data the server shows at
``http://HOST:PORT/``:

- with npm on PATH, unless the bundle there is newer than every source of the
  viewer (then it is packaged as it is);
- without npm, the bundle already there is packaged (the Docker image builds it
  in a stage of its own); with none, the wheel is built without the viewer and
  says so: the server then answers its page with how to build it;
- ``XVIZ_BUILD_VIEWER=0`` builds without running npm at all.

An editable install (``pip install -e .``) skips this step: the package is the
checkout, and ``scripts/build-viewer.sh`` builds the viewer in place.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.errors import SetupError

ROOT = Path(__file__).resolve().parent
SCRIPT = ROOT / "scripts" / "build-viewer.sh"
VIEWER = ROOT / "viewer"
BUNDLE = ROOT / "xviz_server" / "viewer_static"
SOURCES = ["package.json", "package-lock.json", "build.mjs", "src"]


def say(message: str) -> None:
    print(f"xviz-server build: {message}", flush=True)


def bundle_is_current() -> bool:
    """Whether the bundle's page is newer than every file the viewer is built from."""
    page = BUNDLE / "index.html"
    if not page.is_file():
        return False
    sources = [path for name in SOURCES for path in [VIEWER / name, *(VIEWER / name).rglob("*")] if path.is_file()]
    return all(path.stat().st_mtime <= page.stat().st_mtime for path in sources)


def build_viewer() -> None:
    """Build the viewer's bundle into xviz_server/viewer_static/ where that can and should be done."""
    built = (BUNDLE / "index.html").is_file()
    have_sources = SCRIPT.is_file() and (VIEWER / "package.json").is_file()
    if os.environ.get("XVIZ_BUILD_VIEWER") == "0" or not have_sources or shutil.which("npm") is None:
        why = ("XVIZ_BUILD_VIEWER=0" if os.environ.get("XVIZ_BUILD_VIEWER") == "0"
               else "npm not found" if have_sources else "no viewer sources here")
        if built:
            say(f"{why}: packaging the viewer bundle already in {BUNDLE}")
        else:
            say(f"WARNING {why}: building without the viewer page (the server runs, and its page at "
                "http://HOST:PORT/ says the viewer is not built). Install Node.js 18 or newer with npm and build "
                "again, or run scripts/build-viewer.sh first.")
        return
    if bundle_is_current():
        say(f"the viewer bundle in {BUNDLE} is newer than its sources: packaging it as it is")
        return
    say("building the viewer with scripts/build-viewer.sh (npm ci and esbuild)")
    result = subprocess.run(["bash", str(SCRIPT)], cwd=ROOT)
    if result.returncode != 0 or not (BUNDLE / "index.html").is_file():
        raise SetupError(f"scripts/build-viewer.sh failed (exit {result.returncode}, its output is above); "
                         "fix it, or build without the viewer page with XVIZ_BUILD_VIEWER=0")


class BuildPy(build_py):
    """``build_py`` that builds the viewer first (not for an editable install)."""

    def run(self) -> None:
        if not self.editable_mode:
            build_viewer()
        super().run()


setup(cmdclass={"build_py": BuildPy})
