"""Installing as a Python user does: an sdist, a wheel built from it, a fresh virtual environment.

The wheel carries the built-in viewer (setup.py runs scripts/build-viewer.sh
where npm is), and the installed server works from any working directory,
its worker processes included: started at the root of this checkout, whose
``xviz_server/`` folder is not the installed package, it serves the demo's
frames (made in the process pool) and the viewer's page. Without running npm
(none, or XVIZ_BUILD_VIEWER=0, or a bundle newer than its sources) the wheel
still builds and says what it packaged.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import urllib.request
import venv
from pathlib import Path

import pytest

from helpers import clean_env

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
# What the package is built from; the viewer's bundle and npm's folder are made by the build.
SOURCES = [
    "pyproject.toml",
    "setup.py",
    "MANIFEST.in",
    "README.md",
    "xviz_server",
    "providers",
    "schema",
    "viewer",
    "scripts/build-viewer.sh",
]
LEFT_OUT = shutil.ignore_patterns("__pycache__", "viewer_static", "node_modules")


def copy_sources(target: Path) -> Path:
    for name in SOURCES:
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, target / name, ignore=LEFT_OUT)
        else:
            shutil.copy2(REPO / name, target / name)
    return target


def pip_wheel(source: Path, into: Path, path: str, **variables: str) -> subprocess.CompletedProcess[str]:
    """``pip wheel`` of ``source`` (a folder or an sdist) with PATH set to ``path``; the build's output is in stderr."""
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-v",
            "--no-deps",
            "--disable-pip-version-check",
            "-w",
            str(into),
            str(source),
        ],
        capture_output=True,
        text=True,
        env=clean_env(PATH=path, **variables),
        timeout=900,
    )


def viewer_files(wheel: Path) -> list[str]:
    import zipfile

    with zipfile.ZipFile(wheel) as archive:
        return [name for name in archive.namelist() if name.startswith("xviz_server/viewer_static/")]


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh virtual environment holding the wheel built from an sdist of the checkout; its ``bin`` folder."""
    if shutil.which("npm") is None:
        pytest.skip("npm is needed to build the viewer into the wheel")
    work = tmp_path_factory.mktemp("install")
    source = copy_sources(work / "source")
    sdist = subprocess.run(
        [sys.executable, "-m", "build", "--sdist", "--outdir", str(work / "dist"), str(source)],
        capture_output=True,
        text=True,
        env=clean_env(),
        timeout=600,
    )
    assert sdist.returncode == 0, sdist.stdout + sdist.stderr
    (archive,) = (work / "dist").glob("xviz_server-*.tar.gz")
    wheel_build = pip_wheel(archive, work / "dist", clean_env()["PATH"])
    assert wheel_build.returncode == 0, wheel_build.stdout + wheel_build.stderr
    assert "building the viewer with scripts/build-viewer.sh" in wheel_build.stderr
    (wheel,) = (work / "dist").glob("xviz_server-*.whl")
    assert "xviz_server/viewer_static/index.html" in viewer_files(wheel)
    environment = work / "venv"
    venv.EnvBuilder(with_pip=True).create(environment)
    install = subprocess.run(
        [
            str(environment / "bin" / "pip"),
            "install",
            "--quiet",
            "--no-compile",
            "--disable-pip-version-check",
            str(wheel),
        ],
        capture_output=True,
        text=True,
        env=clean_env(),
        timeout=900,
    )
    assert install.returncode == 0, install.stdout + install.stderr
    return environment / "bin"


def test_installed_server_started_in_the_checkout_serves_the_demo_and_the_viewer(installed: Path, tmp_path: Path):
    assert (REPO / "xviz_server" / "__init__.py").is_file()  # the working directory holds another copy
    server = subprocess.Popen(
        [str(installed / "xviz-server"), "serve", "--host", "127.0.0.1", "--port", "0"],
        cwd=REPO,
        env=clean_env(XDG_CACHE_HOME=str(tmp_path / "cache")),
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert server.stderr is not None
        log = []
        for line in server.stderr:  # the demo's datasets start the process pool before the server listens
            log.append(line)
            if found := re.search(r"listening on ws://127\.0\.0\.1:(\d+)/", line):
                port = int(found.group(1))
                break
        else:
            pytest.fail("the server stopped before listening:\n" + "".join(log))
        # The demo's frames are made by jobs in the worker processes.
        probe = subprocess.run(
            [
                str(installed / "xviz-server"),
                "probe",
                "--timeout",
                "60",
                "--end",
                "+1",
                f"ws://127.0.0.1:{port}/?log=demo",
            ],
            cwd=REPO,
            capture_output=True,
            text=True,
            env=clean_env(),
            timeout=120,
        )
        assert probe.returncode == 0, probe.stdout + probe.stderr
        assert re.search(r"xviz/state_update +\d+", probe.stdout) and re.search(r"errors +none", probe.stdout), (
            probe.stdout
        )
        request = urllib.request.Request(f"http://127.0.0.1:{port}/", headers={"Accept": "text/html"})
        with urllib.request.urlopen(request, timeout=30) as response:
            page = response.read().decode()
        script = re.search(r'<script[^>]* src="(viewer-[^"]+\.js)"', page)
        assert script, page
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/{script.group(1)}", timeout=30) as response:
            assert response.status == 200 and len(response.read()) > 100_000
    finally:
        server.terminate()
        _, rest = server.communicate(timeout=30)
    assert "ModuleNotFoundError" not in "".join(log) + rest


@pytest.mark.parametrize(
    ("npm", "variables", "bundle", "said", "packaged"),
    [
        (False, {}, False, "WARNING npm not found: building without the viewer page", False),
        (False, {}, True, "npm not found: packaging the viewer bundle already in", True),
        (
            True,
            {"XVIZ_BUILD_VIEWER": "0"},
            False,
            "WARNING XVIZ_BUILD_VIEWER=0: building without the viewer page",
            False,
        ),
        (True, {}, True, "is newer than its sources: packaging it as it is", True),
    ],
    ids=["no npm", "no npm, a bundle", "XVIZ_BUILD_VIEWER=0", "a bundle newer than its sources"],
)
def test_a_wheel_builds_without_running_npm_and_says_what_it_packaged(
    tmp_path: Path, npm: bool, variables: dict[str, str], bundle: bool, said: str, packaged: bool
):
    source = copy_sources(tmp_path / "source")
    if bundle:  # made after the sources were copied: newer than each of them
        (source / "xviz_server" / "viewer_static").mkdir()
        (source / "xviz_server" / "viewer_static" / "index.html").write_text("<!doctype html>\n")
    # Without npm: only this Python's folder on PATH.
    path = clean_env()["PATH"] if npm else str(Path(sys.executable).parent)
    result = pip_wheel(source, tmp_path / "dist", path, **variables)
    assert result.returncode == 0, result.stdout + result.stderr
    assert said in result.stderr
    (wheel,) = (tmp_path / "dist").glob("xviz_server-*.whl")
    assert viewer_files(wheel) == (["xviz_server/viewer_static/index.html"] if packaged else [])
