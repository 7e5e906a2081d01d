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
# With the broker extra (redis, hiredis): replicas share live feeds with --broker.
"$prefix/bin/pip" install --quiet --no-cache-dir --disable-pip-version-check "$sources[broker]"
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
if command -v strip >/dev/null; then
    # Not the libraries a wheel vendors in NAME.libs/: auditwheel has rewritten
    # them with patchelf, and strip can leave them unloadable (numpy's OpenBLAS).
    find "$site" -type f -name '*.so' -not -path '*.libs/*' -exec strip --strip-unneeded {} +
else
    echo "install.sh: no strip (Debian's binutils): extension modules keep their debug info and symbols" >&2
fi
# Every extension module still loads, and the server's modules import.
"$prefix/bin/python" -I -c 'import numpy.linalg, PIL.Image, PIL.ImageFont, uvloop, obstore, orjson, pydantic, jsonschema, google_crc32c, zlib_ng.zlib_ng, redis, hiredis, xviz_server.server'
"$prefix/bin/xviz-server" --version
