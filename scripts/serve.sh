#!/usr/bin/env bash
# Set up the server on a fresh machine and start it. Arguments go to
# `xviz-server serve`; without --data-dir it serves the built-in demo log
# (generated on first run) on ws://127.0.0.1:3000/, with the viewer page at
# http://127.0.0.1:3000/ when node/npm are there to build it. It installs the
# extras the README's examples use, so that each runs as written: ROS bags and
# MCAP (ros), VISTA traces (vista), live feeds across replicas (broker).
#
# It installs only what changed since the last start: .venv/serve-stamps holds
# a hash of what each install read (the package's pyproject.toml and setup.py;
# the viewer's sources, lockfile and build script). A port in use is reported
# before anything is installed.
set -euo pipefail
cd "$(dirname "$0")/.."

# --host and --port as serve takes them (flag over XVIZ_* variable over default;
# a TOML file's are checked by the server itself).
host=${XVIZ_HOST:-127.0.0.1}
port=${XVIZ_PORT:-3000}
args=("$@")
for ((i = 0; i < ${#args[@]}; i++)); do
    case ${args[i]} in
        --host) host=${args[i + 1]:-$host} ;;
        --host=*) host=${args[i]#--host=} ;;
        --port) port=${args[i + 1]:-$port} ;;
        --port=*) port=${args[i]#--port=} ;;
    esac
done
if ! python3 - "$host" "$port" <<'EOF'
import errno, socket, sys
host, port = sys.argv[1], sys.argv[2]
try:
    port_number = int(port)
    with socket.create_server((host, port_number)):
        pass
except (ValueError, OverflowError):
    pass  # not a port: the server says what is wrong with it
except OSError as exc:
    if exc.errno == errno.EADDRINUSE:
        print(f"serve.sh: cannot listen on {host}:{port}: address already in use; another process listens there: "
              "choose a free port with --port (XVIZ_PORT)", file=sys.stderr)
        sys.exit(2)
EOF
then
    exit 2
fi

source scripts/venv.sh
stamps=.venv/serve-stamps
mkdir -p "$stamps"
stamp() {  # stamp FILE...: one hash of the files' names and contents, and of the Python that installs them
    { python3 --version; find "$@" -type f ! -path '*/node_modules/*' -print0 | sort -z | xargs -0 sha256sum; } | sha256sum | cut -d' ' -f1
}
changed() {  # changed NAME FILE...: whether the files differ from those of NAME's last install
    [ "$(cat "$stamps/$1" 2>/dev/null)" != "$(stamp "${@:2}")" ]
}
package=(pyproject.toml setup.py)
if changed package "${package[@]}"; then
    python -m pip install --quiet --disable-pip-version-check -e ".[ros,vista,broker]"
    stamp "${package[@]}" >"$stamps/package"
fi
viewer=(viewer/package.json viewer/package-lock.json viewer/build.mjs viewer/src scripts/build-viewer.sh)
if changed viewer "${viewer[@]}" || [ ! -f xviz_server/viewer_static/index.html ]; then
    scripts/build-viewer.sh
    if [ -f xviz_server/viewer_static/index.html ]; then stamp "${viewer[@]}" >"$stamps/viewer"; fi
fi
exec xviz-server serve "$@"
