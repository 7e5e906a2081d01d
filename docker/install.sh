#!/bin/sh
# Install xviz-server from this repository into a new virtual environment.
#   docker/install.sh PREFIX
# The Dockerfile's build stage runs exactly this; tests/test_docker.py runs it
# outside Docker.
set -eu
prefix=${1:?usage: docker/install.sh PREFIX}
repo=$(cd "$(dirname "$0")/.." && pwd)
python3 -m venv "$prefix"
"$prefix/bin/pip" install --quiet --no-cache-dir --disable-pip-version-check "$repo"
"$prefix/bin/xviz-server" --version
