#!/usr/bin/env bash
# Set up the server on a fresh machine and start it. Arguments go to
# `xviz-server serve`; without --data-dir it serves the built-in demo log
# (generated on first run) on ws://127.0.0.1:3000/.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/venv.sh
python -m pip install --quiet --disable-pip-version-check -e .
exec xviz-server serve "$@"
