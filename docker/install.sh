#!/bin/sh
# Install xviz-server from this repository into a new virtual environment
# holding only what serving uses.
#   docker/install.sh PREFIX
# The Dockerfile's build stage runs exactly this; tests/test_docker.py runs it
# outside Docker. The package is built from the files it declares
# (pyproject.toml's package-dir), copied apart, so that nothing else in the
# checkout (a stale build/ folder, caches) can reach the environment.
set -eu
prefix=${1:?usage: docker/install.sh PREFIX}
repo=$(cd "$(dirname "$0")/.." && pwd)
sources=$(mktemp -d)
trap 'rm -rf "$sources"' EXIT
(cd "$repo" && tar -cf - --exclude=__pycache__ pyproject.toml setup.py README.md xviz_server providers schema) | tar -xf - -C "$sources"
python3 -m venv "$prefix"
# With the ros extra (rosbags: ROS 1 and 2 bags, MCAP files) and the broker extra
# (redis, hiredis: replicas share live feeds with --broker).
"$prefix/bin/pip" install --quiet --no-cache-dir --disable-pip-version-check "$sources[ros,broker]"
# Serving needs none of: the installer; the dependencies' test suites (numpy's,
# jsonschema's, referencing's, ...) and numpy's extension modules that only its
# tests load (_simd, _*_tests); type stubs; the C headers, static libraries and
# Cython declarations for building against numpy, nor its build tools (f2py, the
# Fortran wrapper generator, and numpy.distutils); the debug info and static
# symbol tables of extension modules, which only a debugger reads (uvloop's debug info is most of its size; Debian strips
# its own packages' libraries the same way).
"$prefix/bin/pip" uninstall --quiet --yes pip setuptools
site=$(echo "$prefix"/lib/python3*/site-packages)
find "$site" -depth -type d -name tests -exec rm -rf {} +
find "$site" -type f \( -name '*.pyi' -o -name '*.h' -o -name '*.a' -o -name '*.pxd' \) -delete
rm -rf "$site/numpy/f2py" "$site/numpy/distutils" "$prefix/bin/f2py" "$prefix/bin/numpy-config"
rm -f "$site"/numpy/_core/_simd.*.so "$site"/numpy/_core/_*_tests.*.so
# Pillow's formats and features that serving never uses (it reads and writes PNG and
# JPEG): AVIF, WebP, colour management (LittleCMS), fonts (FreeType, HarfBuzz, and
# Brotli for FreeType's WOFF2) and Tk, with the libraries the wheel vendors for them
# alone. Their plugins find the module missing and report the format unsupported.
rm -f "$site"/PIL/_avif.*.so "$site"/PIL/_webp.*.so "$site"/PIL/_imagingcms.*.so "$site"/PIL/_imagingft.*.so "$site"/PIL/_imagingtk.*.so
(cd "$site/pillow.libs" && rm -f libavif-* libwebp* libsharpyuv-* liblcms2-* libfreetype-* libharfbuzz-* libbrotli*)
# apsw (SQLite, for rosbags' ROS 2 bags): not the SQLite programs it ships, nor its
# Unicode module (for full-text search).
rm -rf "$site/apsw/sqlite_extra_binaries" "$site"/apsw/_unicode.*.so
if command -v strip >/dev/null; then
    # Not the libraries a wheel vendors in NAME.libs/: auditwheel has rewritten
    # them with patchelf, and strip can leave them unloadable (numpy's OpenBLAS).
    find "$site" -type f -name '*.so' -not -path '*.libs/*' -exec strip --strip-unneeded {} +
else
    echo "install.sh: no strip (Debian's binutils): extension modules keep their debug info and symbols" >&2
fi
# Every extension module still loads, and the server's modules import.
"$prefix/bin/python" -I -c 'import PIL.features; assert PIL.features.check("jpg") and PIL.features.check("zlib")'
"$prefix/bin/python" -I -c 'import numpy.linalg, PIL.Image, uvloop, obstore, orjson, pydantic, jsonschema, google_crc32c, zlib_ng.zlib_ng, redis, hiredis, apsw, rosbags.highlevel, rosbags.rosbag1, rosbags.rosbag2, xviz_server.server, xviz_server.datasets.ros.reindex'
"$prefix/bin/xviz-server" --version
