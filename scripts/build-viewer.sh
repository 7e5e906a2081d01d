#!/usr/bin/env bash
# Build the viewer page that the server shows at http://HOST:PORT/ into
# xviz_server/viewer_static/ (git-ignored). Needs node and npm; without them it
# says so and exits 0: the server runs without a viewer.
set -euo pipefail
cd "$(dirname "$0")/../viewer"
if ! command -v npm >/dev/null 2>&1; then
    echo "build-viewer: npm not found; the server will run without its viewer page" >&2
    exit 0
fi
# --ignore-scripts: baseui (under @streetscape.gl/monochrome) depends on puppeteer,
# whose install script downloads a browser; nothing in the bundle needs an install script.
npm ci --ignore-scripts --no-audit --no-fund --loglevel=error
node build.mjs "$@"
