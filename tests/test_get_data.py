"""scripts/get-data.sh: the real data, checked by size and SHA-256 against scripts/data.sha256.

The data's real host cannot be reached from here, so the script is given the
real shared folder as a folder, and as a tar archive by a ``file://`` URL; and
copies of it with one file changed or cut short, which it must refuse.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tarfile
from pathlib import Path

import pytest

from devkit.data import KITTI_FRAME, SHARED_DIR
from helpers import needs_data

pytestmark = [pytest.mark.slow, needs_data]

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "get-data.sh"
MANIFEST = REPO / "scripts" / "data.sha256"


def get_data(destination: Path, *source: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "XVIZ_SHARED_DIR": str(destination)}
    env.pop("XVIZ_DATA_URL", None)
    return subprocess.run([str(SCRIPT), *source], capture_output=True, text=True, env=env, timeout=600)


def listed() -> list[str]:
    return [line.split(" ", 2)[2] for line in MANIFEST.read_text().splitlines() if line and not line.startswith("#")]


def linked_copy(tmp_path: Path) -> Path:
    """The shared folder's data and corpus as links to its files, which a test may replace one by one."""
    copy = tmp_path / "source"
    for top in ("data", "conformance"):
        shutil.copytree(SHARED_DIR / top, copy / top, copy_function=os.symlink)
    return copy


def test_the_list_is_every_file_of_the_shared_folder():
    files = sorted(
        path.relative_to(SHARED_DIR).as_posix()
        for top in ("data", "conformance")
        for path in (SHARED_DIR / top).rglob("*")
        if path.is_file()
    )
    assert sorted(listed()) == files and len(files) > 400


def test_a_folder_is_checked_and_installed(tmp_path: Path):
    result = get_data(tmp_path / "shared", str(SHARED_DIR))
    assert result.returncode == 0, result.stderr
    assert f"{len(listed())} files" in result.stdout and "checked by size and SHA-256" in result.stdout
    frame = tmp_path / "shared" / KITTI_FRAME.relative_to(SHARED_DIR)
    assert frame.read_bytes() == KITTI_FRAME.read_bytes() and not frame.is_symlink()
    assert sorted(os.listdir(tmp_path / "shared")) == ["conformance", "data"]  # no staging folder left


def test_an_archive_by_file_url_is_checked_and_installed(tmp_path: Path):
    archive = tmp_path / "xviz-shared.tar"
    with tarfile.open(archive, "w") as tar:  # with a top folder, as `tar -cf x.tar shared/` makes it
        for top in ("data", "conformance"):
            tar.add(SHARED_DIR / top, arcname=f"shared/{top}")
        tar.add(REPO / "README.md", arcname="shared/unrelated.md")
    result = get_data(tmp_path / "shared", archive.as_uri())
    assert result.returncode == 0, result.stderr
    installed = sorted(
        path.relative_to(tmp_path / "shared").as_posix() for path in (tmp_path / "shared").rglob("*") if path.is_file()
    )
    assert installed == sorted(listed())  # the files of the list, nothing else


@pytest.mark.parametrize("change", ["one byte", "cut short", "missing"])
def test_a_file_that_differs_stops_it_and_nothing_is_installed(tmp_path: Path, change: str):
    source = linked_copy(tmp_path)
    victim = source / KITTI_FRAME.relative_to(SHARED_DIR)
    data = bytearray(KITTI_FRAME.read_bytes())
    victim.unlink()
    if change == "one byte":
        data[len(data) // 2] ^= 1
        victim.write_bytes(bytes(data))
    elif change == "cut short":
        victim.write_bytes(bytes(data[:-1]))
    (tmp_path / "shared" / "data").mkdir(parents=True)  # what was there stays
    result = get_data(tmp_path / "shared", str(source))
    assert result.returncode == 1
    why = {"one byte": "SHA-256 differs", "cut short": f"{len(data) - 1} bytes, not {len(data)}", "missing": "missing"}[
        change
    ]
    assert (
        f"1 of {len(listed())} files" in result.stderr
        and f"{KITTI_FRAME.relative_to(SHARED_DIR)}: {why}" in result.stderr
    )
    assert "nothing was installed" in result.stderr and os.listdir(tmp_path / "shared" / "data") == []


def test_without_a_source_it_says_where_the_data_comes_from(tmp_path: Path):
    result = get_data(tmp_path / "shared")
    assert result.returncode == 2 and not (tmp_path / "shared").exists()
    assert "https://www.cvlibs.net/datasets/kitti/raw_data.php" in result.stderr
    assert "2011_09_26_drive_0001_sync.zip" in result.stderr and "2011_09_26_calib.zip" in result.stderr


def test_something_that_is_not_an_archive_is_refused(tmp_path: Path):
    (tmp_path / "data.tar").write_text("not a tar file\n")
    result = get_data(tmp_path / "shared", (tmp_path / "data.tar").as_uri())
    assert result.returncode == 1 and "not a tar archive of the data" in result.stderr
    assert os.listdir(tmp_path / "shared") == []
