#!/bin/sh
# The container's entry point: `xviz-server` with the arguments given (default:
# `serve`), configured through XVIZ_* variables, flags and XVIZ_CONFIG,
# listening on all interfaces of the container (XVIZ_HOST, which wins over
# the file's host). It serves the log store mounted at /data;
# with nothing there (and no XVIZ_DATA_DIR), the built-in demo log. exec
# makes xviz-server PID 1's process, so it receives SIGTERM and closes its
# sessions (1001) before the orchestrator's grace period ends, and
# `xviz-server healthcheck --pid 1` reads its settings.
set -eu
export XVIZ_HOST="${XVIZ_HOST:-0.0.0.0}"
if [ -z "${XVIZ_DATA_DIR+set}" ] && [ -n "$(ls -A /data 2>/dev/null)" ]; then
    export XVIZ_DATA_DIR=/data
fi
if [ "$#" -eq 0 ]; then
    set -- serve
fi
exec xviz-server "$@"
