#!/usr/bin/env bash
# Set up everything the test suite needs on a fresh machine, then run it.
# Needs only python3 (>= 3.10) and node/npm; extra arguments go to pytest.
# The package is type-checked with mypy first (scripts/typecheck.sh).
# --quick (first) runs the fast tier only: the tests not marked slow (docs/testing.md).
set -euo pipefail
cd "$(dirname "$0")/.."
quick=0
if [ "${1:-}" = "--quick" ]; then
    quick=1
    shift
    set -- -m "not slow" "$@"
fi
source scripts/venv.sh
python -m pip install --quiet --disable-pip-version-check -e ".[test,vista,ros,broker,parquet,pandaset]" -e ./devkit
npm ci --prefix tests/interop --no-audit --no-fund --loglevel=error
# The viewer's browser tests: the bundle, playwright-core (in viewer/) and Debian's chromium.
scripts/build-viewer.sh
if ! command -v chromium >/dev/null 2>&1; then
    apt-get update -q && apt-get install -y -q chromium
fi
# The broker tests (live feeds across replicas) run Debian's redis-server.
if ! command -v redis-server >/dev/null 2>&1; then
    apt-get update -q && apt-get install -y -q redis-server
fi
# The real Lichtblick app's tests (slow tier): its web app built from tests/vendor/lichtblick/, once per
# machine (kept in ~/.cache/xviz-server; a first build takes about 5 min on 2 cores), with corepack (node's own builds
# have it, Debian's nodejs not: installed from npm then) and xz (Debian's xz-utils, not in every image).
# A failed build fails the run.
# XVIZ_LICHTBLICK_DIR set (empty: skip those tests) is used as it is.
if [ "$quick" = 0 ] && [ -z "${XVIZ_LICHTBLICK_DIR+set}" ]; then
    if ! command -v corepack >/dev/null 2>&1; then
        npm install --global --no-audit --no-fund --loglevel=error corepack@0.34.6
    fi
    if ! command -v xz >/dev/null 2>&1; then
        apt-get update -q && apt-get install -y -q xz-utils
    fi
    XVIZ_LICHTBLICK_DIR=$(scripts/build-lichtblick.sh)
    export XVIZ_LICHTBLICK_DIR
fi
scripts/typecheck.sh
exec python -m pytest "$@"
