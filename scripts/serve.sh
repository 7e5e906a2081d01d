#!/usr/bin/env bash
# Set up the server on a fresh machine and start it; arguments go to
# `xviz-server serve` (default: the built-in demo log on port 3000).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/venv.sh
python -m pip install --quiet --disable-pip-version-check -e .
exec xviz-server --version
