#!/usr/bin/env bash
# Get the real data the tests read: the KITTI excerpt (data/) and the XVIZ
# conformance corpus (conformance/), into the shared folder the tests look in
# ($XVIZ_SHARED_DIR, default ../shared beside the repository).
#
#   scripts/get-data.sh SOURCE
#
# SOURCE is the project's data archive (a tar file, compressed or not, holding
# data/ and conformance/, at its top or in one folder) by URL (https://,
# file://) or path, or a folder holding data/ and conformance/ (another
# checkout's shared folder); $XVIZ_DATA_URL when no argument is given. Every
# file is checked by its size and SHA-256 against scripts/data.sha256 before
# anything is put in place; a file that differs stops it (exit 1), naming the
# file. Files of the archive not in that list are left out.
#
# Where the data comes from (docs/testing.md): the KITTI raw dataset,
# https://www.cvlibs.net/datasets/kitti/raw_data.php (CC BY-NC-SA 3.0): drive
# 2011_09_26_drive_0001, files 2011_09_26_drive_0001_sync.zip and
# 2011_09_26_calib.zip, converted by the official XVIZ KITTI converter; the
# corpus from the public uber/xviz repository (Apache-2.0).
set -euo pipefail
cd "$(dirname "$0")/.."
source=${1:-${XVIZ_DATA_URL:-}}
if [ -z "$source" ]; then
    cat >&2 <<'EOF'
usage: scripts/get-data.sh SOURCE   (or set XVIZ_DATA_URL)
SOURCE: the project's data archive (URL or path), or a folder holding data/ and conformance/.
The data is 25 frames of the KITTI raw dataset (https://www.cvlibs.net/datasets/kitti/raw_data.php,
drive 2011_09_26_drive_0001: 2011_09_26_drive_0001_sync.zip, 2011_09_26_calib.zip; CC BY-NC-SA 3.0)
and the XVIZ conformance corpus (uber/xviz); see docs/testing.md.
EOF
    exit 2
fi
exec python3 - "$source" "${XVIZ_SHARED_DIR:-$(dirname "$(pwd)")/shared}" scripts/data.sha256 <<'PY'
import hashlib, os, shutil, sys, tarfile, tempfile, urllib.parse, urllib.request
from pathlib import Path

source, destination, manifest = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
TOPS = ("data", "conformance")
expected = {}
for line in manifest.read_text().splitlines():
    if line and not line.startswith("#"):
        digest, size, name = line.split(" ", 2)
        expected[name] = (digest, int(size))


def fail(message):
    print(f"get-data: {message}", file=sys.stderr)
    sys.exit(1)


def digest_of(path):
    hash = hashlib.sha256()
    with open(path, "rb") as file:
        while chunk := file.read(1 << 20):
            hash.update(chunk)
    return hash.hexdigest()


def check(root):
    """The files under root that are missing or differ from the manifest, each with why."""
    problems = []
    for name, (digest, size) in expected.items():
        path = root / name
        if not path.is_file():
            problems.append(f"{name}: missing")
        elif path.stat().st_size != size:
            problems.append(f"{name}: {path.stat().st_size} bytes, not {size}")
        elif digest_of(path) != digest:
            problems.append(f"{name}: SHA-256 differs from scripts/data.sha256")
    return problems


def unpack(archive, staging):
    """The manifest's files of the tar file, with or without one top folder, written below staging."""
    with tarfile.open(archive, "r:*") as tar:
        for member in tar:
            parts = Path(member.name).parts
            parts = parts[1:] if parts[:1] == (".",) else parts
            if parts and parts[0] not in TOPS:
                parts = parts[1:]  # one top folder (shared/, or the archive's name)
            name = "/".join(parts)
            if member.isfile() and name in expected:
                target = staging / name
                target.parent.mkdir(parents=True, exist_ok=True)
                with tar.extractfile(member) as data, open(target, "wb") as out:
                    shutil.copyfileobj(data, out)


scheme = urllib.parse.urlsplit(source).scheme
local = Path(urllib.request.url2pathname(urllib.parse.urlsplit(source).path)) if scheme == "file" else None
local = local or (None if scheme in ("http", "https") else Path(source))
destination.mkdir(parents=True, exist_ok=True)
staging = Path(tempfile.mkdtemp(prefix=".get-data-", dir=destination))
try:
    if local is not None and local.is_dir():
        root = local
    else:
        archive = local
        if archive is None:
            archive = staging / "archive"
            print(f"get-data: fetching {source}", file=sys.stderr)
            try:
                with urllib.request.urlopen(source, timeout=60) as answer, open(archive, "wb") as out:
                    shutil.copyfileobj(answer, out)
            except OSError as exc:
                fail(f"{source}: {exc}")
        try:
            unpack(archive, staging)
        except (OSError, tarfile.TarError) as exc:
            fail(f"{source}: not a tar archive of the data ({exc})")
        root = staging
    problems = check(root)
    if problems:
        shown = "\n  ".join(problems[:10]) + (f"\n  ... and {len(problems) - 10} more" if len(problems) > 10 else "")
        fail(f"{len(problems)} of {len(expected)} files are not the data scripts/data.sha256 lists; nothing was installed:\n  {shown}")
    if root.resolve() != destination.resolve():
        for top in TOPS:
            if root is staging:
                new = staging / top
            else:
                new = staging / f"new-{top}"
                for name in expected:
                    if name.startswith(f"{top}/"):
                        (new / name[len(top) + 1:]).parent.mkdir(parents=True, exist_ok=True)
                        shutil.copyfile(root / name, new / name[len(top) + 1:])
            old = destination / top
            if old.exists() or old.is_symlink():
                old.rename(staging / f"old-{top}")
            new.rename(old)
    total = sum(size for _, size in expected.values())
    print(f"get-data: {len(expected)} files ({total / 1e6:.0f} MB) checked by size and SHA-256, in {destination}")
finally:
    shutil.rmtree(staging, ignore_errors=True)
PY
