#!/usr/bin/env bash
# Type-check with mypy: the package as it is installed, then the benchmarks (scripts/bench/)
# and the helpers they share with the tests (devkit/) against it; then ruff: the layout
# (ruff format --check) and the lint rules (ruff check) of pyproject.toml's [tool.ruff]. providers/ and schema/
# sit inside xviz_server/ when installed (pyproject.toml's package-dir), so mypy reads a
# tree of links laid out that way; last, commit subjects are held to 72 characters. Reported paths are as installed
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
# Commit subjects: at most 72 characters, for every commit after the one that set the rule
# (the merges' too). Skipped where that commit is not in the history (a shallow clone, an export).
rule=f9f68ca
if git rev-parse -q --verify "$rule^{commit}" >/dev/null 2>&1; then
    long=$(git log --format=%s "$rule..HEAD" | awk 'length($0) > 72')
    if [ -n "$long" ]; then
        printf 'commit subjects over 72 characters (reword them before merging):\n%s\n' "$long" >&2
        exit 1
    fi
fi
