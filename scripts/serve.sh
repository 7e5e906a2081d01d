#!/usr/bin/env bash
# Set up the server on a fresh machine and start it. Arguments go to
# `xviz-server serve`; without --data-dir it serves the built-in demo log
# (generated on first run) on ws://127.0.0.1:3000/, with the viewer page at
# http://127.0.0.1:3000/ when node/npm are there to build it. It installs the
# extras the README's examples use, so that each runs as written: ROS bags and
# MCAP (ros), VISTA traces (vista), live feeds across replicas (broker).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/venv.sh
python -m pip install --quiet --disable-pip-version-check -e ".[ros,vista,broker]"
scripts/build-viewer.sh
exec xviz-server serve "$@"
