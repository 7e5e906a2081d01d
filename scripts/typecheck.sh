#!/usr/bin/env bash
# Type-check with mypy: the package as it is installed, then the benchmarks (scripts/bench/)
# and the helpers they share with the tests (devkit/) against it; then ruff: the layout
# (ruff format --check) and the lint rules (ruff check) of pyproject.toml's [tool.ruff]. providers/ and schema/
# sit inside xviz_server/ when installed (pyproject.toml's package-dir), so mypy reads a
# tree of links laid out that way. Reported paths are as installed
# (xviz_server/providers/static_log.py is providers/static_log.py here).
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
tree=$(mktemp -d)
trap 'rm -rf "$tree"' EXIT
mkdir "$tree/xviz_server"
cp -rs "$repo/xviz_server/." "$tree/xviz_server/"
cp -rs "$repo/providers" "$tree/xviz_server/providers"
cp -rs "$repo/devkit" "$tree/devkit"
cd "$tree"
"${PYTHON:-python}" -m mypy --config-file "$repo/pyproject.toml" -p xviz_server "$@"
cd "$repo/scripts/bench"
MYPYPATH="$tree" "${PYTHON:-python}" -m mypy --config-file "$repo/pyproject.toml" kit *.py "$tree/devkit" "$@"
cd "$repo"
"${PYTHON:-python}" -m ruff format --check --quiet xviz_server providers tests scripts devkit
"${PYTHON:-python}" -m ruff check --quiet xviz_server providers tests scripts devkit
