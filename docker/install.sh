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
(cd "$repo" && tar -cf - --exclude=__pycache__ pyproject.toml README.md xviz_server providers schema) | tar -xf - -C "$sources"
python3 -m venv "$prefix"
# With the broker extra (redis, hiredis): replicas share live feeds with --broker.
"$prefix/bin/pip" install --quiet --no-cache-dir --disable-pip-version-check "$sources[broker]"
# Serving needs neither the installer nor numpy's own test suite.
"$prefix/bin/pip" uninstall --quiet --yes pip setuptools
find "$prefix/lib" -depth -type d -name tests -path "*/numpy/*" -exec rm -rf {} +
"$prefix/bin/xviz-server" --version
