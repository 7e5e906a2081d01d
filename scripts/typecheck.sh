#!/usr/bin/env bash
# Type-check the package with mypy, as it is installed: providers/ and schema/
# sit inside xviz_server/ there (pyproject.toml's package-dir), so mypy reads a
# tree of links laid out that way. Reported paths are as installed
# (xviz_server/providers/static_log.py is providers/static_log.py here).
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
tree=$(mktemp -d)
trap 'rm -rf "$tree"' EXIT
mkdir "$tree/xviz_server"
cp -rs "$repo/xviz_server/." "$tree/xviz_server/"
cp -rs "$repo/providers" "$tree/xviz_server/providers"
cd "$tree"
exec "${PYTHON:-python}" -m mypy --config-file "$repo/pyproject.toml" -p xviz_server "$@"
