#!/bin/sh
# The container's entry point: `xviz-server` with the arguments given (default:
# `serve`), configured through XVIZ_* variables, flags and XVIZ_CONFIG,
# listening on all interfaces of the container (XVIZ_HOST, which wins over
# the file's host). It serves the log store mounted at /data, even while
# empty (logs added later are served on the first request that names them);
# with nothing mounted there (and no XVIZ_DATA_DIR), the built-in demo log.
# exec makes xviz-server PID 1's process, so it receives SIGTERM and closes
# its sessions (1001) before the orchestrator's grace period ends, and
# `xviz-server healthcheck --pid 1` reads its settings.
set -eu
export XVIZ_HOST="${XVIZ_HOST:-0.0.0.0}"
if [ "$#" -eq 0 ]; then
    set -- serve
fi
if [ -z "${XVIZ_DATA_DIR+set}" ] && [ "$1" = serve ]; then
    # Field 5 of a mountinfo line is the mount point.
    if awk '$5 == "/data" { found = 1 } END { exit !found }' /proc/self/mountinfo || [ -n "$(ls -A /data 2>/dev/null)" ]; then
        export XVIZ_DATA_DIR=/data
    else
        echo "xviz-server: nothing is mounted at /data: serving the built-in demo log; to serve your logs, mount their folder there (docker run -v /path/to/logs:/data:ro ...)" >&2
    fi
fi
exec xviz-server "$@"
