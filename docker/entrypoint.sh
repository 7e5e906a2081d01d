#!/bin/sh
# The container's entry point: `xviz-server` with the arguments given (default:
# `serve`), configured through XVIZ_* variables and flags, listening on all
# interfaces of the container. exec makes xviz-server PID 1's process, so it
# receives SIGTERM and closes its sessions (1001) before the orchestrator's
# grace period ends.
set -eu
export XVIZ_HOST="${XVIZ_HOST:-0.0.0.0}"
export XVIZ_PORT="${XVIZ_PORT:-3000}"
if [ "$#" -eq 0 ]; then
    set -- serve
fi
exec xviz-server "$@"
