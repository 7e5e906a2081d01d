#!/usr/bin/env bash
# Build the Docker image and check it as an operator meets it: health (plain,
# TLS, port by flag and by TOML file), the user it runs as, the demo and the
# built-in viewer with nothing mounted, the `convert` service writing into the
# store of a running server, a store mounted at start, a ROS 1 bag and an MCAP
# file written from the real KITTI excerpt served as they are, the image's
# size over its base (at most 125 MB), the operator's mistakes
# (a read-only store, an unreadable certificate, a bad port) each told in one
# line, no token in the logs, what the image holds, a SIGTERM stop with a
# session open, and compose.yaml's replicas profile (Redis, three replicas and
# the proxy) carrying a live feed to a viewer on every replica.
# Prints the image size, build time, time to healthy and stop time.
#
# Engine: docker when an engine answers; else podman, installed from Debian
# packages when missing (as root), with runc, the container's ulimits set in
# a containers.conf given by CONTAINERS_CONF, and base images (Python for the
# image, Node for the viewer's build stage, Redis and nginx for compose.yaml)
# made by mmdebstrap from the Debian release the Dockerfile names (no registry
# needed), and podman-compose from PyPI.
# Where no engine can run containers, it says so and exits 0.
# Every engine command has a time limit: the script cannot hang CI.
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
run_id=xviz-ci-$$
image=${XVIZ_TEST_IMAGE:-localhost/xviz-server:ci}
budget_mb=125  # what the image may add to its base (docker/README.md)
work=$(mktemp -d)
failures=0
containers=()
project=""

cleanup() {
    [ -z "$project" ] || limit=120 e_compose down -v >/dev/null 2>&1 || true
    for name in "${containers[@]}"; do
        timeout 60 "$engine" rm -f "$name" >/dev/null 2>&1 || true
    done
    rm -rf "$work"
}
engine=true
trap cleanup EXIT

say() { printf '%s\n' "test-image: $*"; }
skip() { say "SKIPPED, no container engine can run here: $*"; exit 0; }
check() {  # check DESCRIPTION COMMAND...: run COMMAND, report, count failures
    local what=$1
    shift
    if "$@"; then say "ok   $what"; else say "FAIL $what"; failures=$((failures + 1)); fi
}
seconds() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$(seconds)" 'BEGIN { printf "%.1f", b - a }'; }
e() { timeout "${limit:-120}" "$engine" "$@"; }
free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

# -- the engine ---------------------------------------------------------------
apt_install() {  # apt_install PACKAGE...: as root, from Debian packages
    [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null || return 1
    say "installing $* from Debian packages"
    timeout 600 apt-get update -qq >/dev/null &&
        DEBIAN_FRONTEND=noninteractive timeout 900 apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}
if ! command -v curl >/dev/null || ! command -v openssl >/dev/null; then
    apt_install curl openssl ca-certificates || { say "FAIL curl and openssl are missing and cannot be installed"; exit 1; }
fi
base_arg=()
build_extra=()
if command -v docker >/dev/null && timeout 20 docker info >/dev/null 2>&1; then
    engine=docker
else
    if ! command -v podman >/dev/null || ! command -v mmdebstrap >/dev/null || ! command -v iptables >/dev/null; then
        apt_install podman runc mmdebstrap iptables uidmap netavark aardvark-dns slirp4netns \
            || skip "no docker engine, and podman could not be installed (root and apt-get are needed)"
    fi
    engine=podman
    # runc (crun refuses a cgroup v1/v2 hybrid); ulimits the process may set
    # without CAP_SYS_RESOURCE: nofile at the hard limit, nproc within pid_max.
    nofile=$(ulimit -Hn)
    nproc=$(cat /proc/sys/kernel/pid_max)
    cat >"$work/containers.conf" <<EOF
[containers]
default_ulimits = ["nofile=$nofile:$nofile", "nproc=$nproc:$nproc"]
[engine]
runtime = "runc"
cgroup_manager = "cgroupfs"
events_logger = "file"
EOF
    export CONTAINERS_CONF=$work/containers.conf
    # No registry: bases made of the Debian release the Dockerfile's BASE_IMAGE names.
    release=$(sed -n 's/^ARG BASE_IMAGE=.*-\([a-z]*\)$/\1/p' docker/Dockerfile)
    make_base() {  # make_base IMAGE PACKAGES [CHANGE]: mmdebstrap a minimal $release with PACKAGES, unless IMAGE exists
        e image exists "$1" && return 0
        say "making the base image $1 with mmdebstrap"
        local started
        started=$(seconds)
        limit=900 timeout 900 mmdebstrap --quiet --variant=minbase --include="$2" "$release" "$work/base.tar" \
            || skip "mmdebstrap could not make a $release base"
        limit=300 e import --quiet ${3:+--change "$3"} "$work/base.tar" "$1" >/dev/null
        rm -f "$work/base.tar"
        say "base image $1 made in $(elapsed "$started") s"
    }
    base=localhost/xviz-base:$release
    node_base=localhost/xviz-node:$release
    make_base "$base" python3,python3-venv,python3-pip,ca-certificates,passwd
    make_base "$node_base" nodejs,npm,ca-certificates
    base_arg=(--build-arg "BASE_IMAGE=$base" --build-arg "NODE_IMAGE=$node_base")
    # compose.yaml's Redis and proxy, for its replicas profile: Debian's redis-server and nginx
    REDIS_IMAGE=localhost/xviz-redis:$release
    PROXY_IMAGE=localhost/xviz-nginx:$release
    export REDIS_IMAGE PROXY_IMAGE
    make_base "$REDIS_IMAGE" redis-server
    make_base "$PROXY_IMAGE" nginx 'CMD ["nginx", "-g", "daemon off;"]'
    # RUN steps reach the package index through the host's proxy, whose CA is
    # in the host's bundle: mounted for RUN steps only, never in a layer.
    bundle=/etc/ssl/certs/ca-certificates.crt
    # npm trusts only its own CAs unless told (a build argument of the viewer's stage).
    [ -f "$bundle" ] && build_extra=(-v "$bundle:$bundle:ro" --build-arg "NODE_EXTRA_CA_CERTS=$bundle")
    build_extra+=(--format docker)  # else podman drops HEALTHCHECK
    e run --rm "$base" true >/dev/null 2>&1 || skip "podman cannot start a container on this machine"
fi
say "engine: $engine ($($engine --version))"

# compose, for compose.yaml's profiles: docker's plugin, or podman-compose from PyPI (Debian's
# 1.0.3 has no profiles) in a virtual environment of its own.
compose=()
if [ "$engine" = docker ]; then
    docker compose version >/dev/null 2>&1 && compose=(docker compose)
elif python3 -m venv "$work/compose" >/dev/null 2>&1 &&
        timeout 300 "$work/compose/bin/pip" install -q 'podman-compose==1.6.0' >"$work/pip.log" 2>&1; then
    compose=("$work/compose/bin/podman-compose")
fi
e_compose() { timeout "${limit:-120}" "${compose[@]}" -p "$project" -f docker/compose.yaml --profile replicas "$@"; }

# -- build --------------------------------------------------------------------
started=$(seconds)
limit=900 e build --quiet "${base_arg[@]}" "${build_extra[@]}" -f docker/Dockerfile -t "$image" . >"$work/build.log" 2>&1 \
    || { cat "$work/build.log"; say "FAIL the image does not build"; exit 1; }
build_time=$(elapsed "$started")
size=$(e image inspect --format '{{.Size}}' "$image")
base_size=$(e image inspect --format '{{.Size}}' "${base:-$(sed -n 's/^ARG BASE_IMAGE=//p' docker/Dockerfile)}" 2>/dev/null || echo "")

# -- helpers for containers ---------------------------------------------------
start() {  # start NAME ARGS...: run a container in the background
    local name=$run_id-$1
    shift
    containers+=("$name")
    e run -d --name "$name" "$@" >/dev/null 2>>"$work/engine.log"
}
healthy() {  # healthy NAME: the image's own HEALTHCHECK command passes
    if [ "$engine" = podman ]; then
        e healthcheck run "$run_id-$1" >/dev/null 2>&1
    else
        e exec "$run_id-$1" xviz-server healthcheck --pid 1 >/dev/null 2>&1
    fi
}
wait_healthy() {  # wait_healthy NAME: poll for 60 s at most
    local deadline=$((SECONDS + 60))
    until healthy "$1"; do
        [ "$SECONDS" -lt "$deadline" ] || return 1
        [ "$(e inspect --format '{{.State.Running}}' "$run_id-$1")" = true ] || return 1
        sleep 0.2
    done
}
logs() { e logs "$run_id-$1" 2>&1; }
in_image() { e exec "$run_id-plain" "$@"; }
catalog_has() {  # catalog_has URL NAME...: GET URL lists every log NAME
    local body
    body=$(curl -sf --max-time 10 "$1") || return 1
    shift
    for name in "$@"; do grep -q "\"name\": \"$name\"" <<<"$body" || return 1; done
}

# -- plain, nothing mounted: the demo; uid; token redacted; what the image holds
port=$(free_port)
started=$(seconds)
start plain -p "127.0.0.1:$port:3000" -e XVIZ_VIEWER_TOKEN=s3cret-ci-token "$image"
check "healthy with nothing mounted" wait_healthy plain
time_to_healthy=$(elapsed "$started")
check "runs as uid 10001" test "$(in_image id -u)" = 10001
check "serves the demo with nothing mounted" catalog_has "http://127.0.0.1:$port/?token=s3cret-ci-token" demo
check "nothing mounted: one line says where to mount the store" grep -q "nothing is mounted at /data.*-v /path/to/logs:/data" <<<"$(logs plain)"
viewer_page() {  # the page at / for a browser, and its script
    local page script
    page=$(curl -sf --max-time 10 -H 'Accept: text/html' "http://127.0.0.1:$port/") || return 1
    script=$(sed -n 's/.*<script[^>]* src="\(viewer-[^"]*\.js\)".*/\1/p' <<<"$page")
    [ -n "$script" ] && curl -sf --max-time 10 -H 'Accept-Encoding: gzip' -o /dev/null "http://127.0.0.1:$port/$script"
}
check "the built-in viewer: the page and its script are served" viewer_page
check "the demo reaches a client (probe, GLB and JSON)" \
    in_image sh -c 'xviz-server probe --timeout 60 "ws://127.0.0.1:3000/?log=demo&token=s3cret-ci-token" >/dev/null &&
                    xviz-server probe --timeout 60 --format json "ws://127.0.0.1:3000/?log=demo&token=s3cret-ci-token" >/dev/null'
check "healthcheck says unhealthy where no server answers" sh -c "! $engine exec $run_id-plain xviz-server healthcheck --port 9 2>/dev/null"
check "/healthz needs no token" test "$(curl -sf --max-time 10 "http://127.0.0.1:$port/healthz")" = ok
check "the session was logged with its token redacted" grep -q "token=REDACTED" <<<"$(logs plain)"
check "the token is in no log line" test "$(logs plain | grep -c s3cret-ci-token)" = 0
check "config does not print the token" test "$(in_image xviz-server config | grep -c s3cret-ci-token)" = 0
check "no pip, setuptools or pkg_resources in the environment" \
    in_image python3 -c 'import importlib.util as u, sys; sys.exit(any(u.find_spec(m) for m in ("pip", "setuptools", "pkg_resources")))'
check "no numpy tests, no sources, no compiler" \
    in_image sh -c '! find /opt/xviz -path "*/numpy/*" -name tests | grep -q . && ! test -e /src && ! command -v gcc && ! command -v cc'
expected=$( (cd xviz_server && find . -name '*.py'
              cd ../providers && find . -name '*.py' | sed 's|^\./|./providers/|'
              cd ../schema && find . -name '*.py' | sed 's|^\./|./schema/|') | sort)
held=$(in_image python3 -c 'import pathlib, xviz_server
root = pathlib.Path(xviz_server.__file__).parent
print("\n".join(sorted("./" + str(p.relative_to(root)) for p in root.rglob("*.py"))))' | sort)
check "the package holds exactly the repository's modules" test "$expected" = "$held"

# SIGTERM with a session open: the client sees 1001, the server exits 0.
python=$repo/.venv/bin/python
if [ -x "$python" ]; then
    timeout 60 "$python" - "$port" >"$work/session.out" 2>&1 <<'EOF' &
import asyncio, sys
from websockets.asyncio.client import connect
async def main():
    async with connect(f"ws://127.0.0.1:{sys.argv[1]}/?log=demo&token=s3cret-ci-token", open_timeout=20) as ws:
        await ws.recv()
        print("open", flush=True)
        await ws.wait_closed()
        print(ws.close_code, flush=True)
asyncio.run(main())
EOF
    client=$!
    deadline=$((SECONDS + 30))
    until grep -q open "$work/session.out" || [ "$SECONDS" -ge "$deadline" ]; do sleep 0.1; done
    started=$(seconds)
    e stop -t 20 "$run_id-plain" >/dev/null 2>>"$work/engine.log"
    stop_time=$(elapsed "$started")
    wait "$client" || true
    check "SIGTERM closes the open session with 1001" test "$(tail -1 "$work/session.out")" = 1001
    check "SIGTERM: the server exits 0" test "$(e inspect --format '{{.State.ExitCode}}' "$run_id-plain")" = 0
else
    say "SKIPPED the SIGTERM check: no $python (run scripts/test.sh first)"
    stop_time=n/a
fi

# -- TLS, with the port in a TOML file ------------------------------------------
tls=$work/tls
mkdir -m 755 "$tls"
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 1 -subj /CN=localhost \
    -addext subjectAltName=IP:127.0.0.1 -keyout "$tls/key.pem" -out "$tls/cert.pem" 2>/dev/null
printf 'port = 8443\ncertfile = "/tls/cert.pem"\nkeyfile = "/tls/key.pem"\n' >"$tls/server.toml"
chown 10001 "$tls/key.pem" 2>/dev/null || chmod 644 "$tls/key.pem"
chmod 644 "$tls/cert.pem" "$tls/server.toml"
port=$(free_port)
start tls -p "127.0.0.1:$port:8443" -v "$tls:/tls:ro" -e XVIZ_CONFIG=/tls/server.toml "$image"
check "TLS (port 8443 from the TOML file): healthy" wait_healthy tls
check "TLS: https answers with the certificate" test "$(curl -sf --max-time 10 --cacert "$tls/cert.pem" "https://127.0.0.1:$port/healthz")" = ok
key_alone() {  # exits non-zero at once, saying what to give
    local out
    if out=$(limit=60 e run --rm -e XVIZ_KEYFILE=/tls/key.pem -v "$tls:/tls:ro" "$image" 2>&1); then return 1; fi
    grep -q 'without --certfile' <<<"$out"
}
check "a key without a certificate: exits non-zero at once, naming the fix" key_alone
cp "$tls/key.pem" "$tls/private.pem"
chmod 600 "$tls/private.pem"
chown 0 "$tls/private.pem" 2>/dev/null || true
unreadable() {  # a key the server's user cannot read: exits non-zero at once, naming the file
    local out
    if out=$(limit=60 e run --rm -e XVIZ_CERTFILE=/tls/cert.pem -e XVIZ_KEYFILE=/tls/private.pem -v "$tls:/tls:ro" "$image" 2>&1); then return 1; fi
    grep -q -- '--keyfile /tls/private.pem: Permission denied' <<<"$out" && ! grep -q Traceback <<<"$out"
}
if [ "$(id -u)" -eq 0 ]; then
    check "an unreadable key: exits non-zero at once, naming it" unreadable
fi

# -- port by flag ----------------------------------------------------------------
port=$(free_port)
start flag -p "127.0.0.1:$port:8080" "$image" serve --port 8080
check "serve --port 8080: healthy" wait_healthy flag
check "serve --port 8080: answers there" test "$(curl -sf --max-time 10 "http://127.0.0.1:$port/healthz")" = ok
bad_port() {  # a port that cannot be: exits non-zero at once, naming the setting
    local out
    if out=$(limit=60 e run --rm -e XVIZ_PORT=70000 "$image" 2>&1); then return 1; fi
    grep -q -- '--port: Input should be less than or equal to 65535' <<<"$out" && ! grep -q Traceback <<<"$out"
}
check "XVIZ_PORT=70000: exits non-zero at once, naming the setting" bad_port

# -- the convert service writes into the store a running server serves (as compose runs them)
raw=$repo/../shared/data/kitti-raw-2011_09_26_drive_0001-head/2011_09_26
if [ -d "$raw" ]; then
    mkdir -p "$work/store"
    chown 10001 "$work/store" 2>/dev/null || chmod 777 "$work/store"
    port=$(free_port)
    start compose -p "127.0.0.1:$port:3000" -v "$work/store:/data:ro" "$image"
    check "an empty store: healthy" wait_healthy compose
    check "an empty store: served, and one line says it has no logs yet" grep -q "no logs under /data yet" <<<"$(logs compose)"
    convert() {  # as docker/compose.yaml runs it: the date folder at /raw, the store at /data
        limit=300 e run --rm -v "$raw:/raw:ro" -v "$work/store:/data" "$image" \
            convert kitti /raw /data/kitti --frames 0:10 >"$work/convert.log" 2>&1 || { cat "$work/convert.log"; return 1; }
    }
    started=$(seconds)
    check "convert: the KITTI date folder mounted at /raw becomes a log in the store" convert
    say "convert took $(elapsed "$started") s"
    probe_store() { e exec "$run_id-$1" xviz-server probe --timeout 60 "ws://127.0.0.1:3000/?log=kitti" >/dev/null; }
    check "a log that appears in the store after start is served" probe_store compose
    port=$(free_port)
    start store -p "127.0.0.1:$port:3000" -v "$work/store:/data:ro" "$image"
    check "a mounted store: healthy" wait_healthy store
    check "a mounted store: its logs are served, not the demo" \
        sh -c "curl -sf --max-time 10 http://127.0.0.1:$port/ | grep -q '\"name\": \"kitti\"' && ! curl -sf --max-time 10 http://127.0.0.1:$port/ | grep -q '\"name\": \"demo\"'"
    check "a mounted store: a client reads the converted log" probe_store store
    refused() {  # refused PATTERN ARGS...: the container exits non-zero at once with one line matching PATTERN, no traceback
        local pattern=$1 out
        shift
        if out=$(limit=120 e run --rm "$@" 2>&1); then return 1; fi
        grep -q "$pattern" <<<"$out" && ! grep -q Traceback <<<"$out"
    }
    check "a read-only store with --record: refused at once, saying so" \
        refused "record /data/recorded: cannot write there (Read-only file system)" -v "$work/store:/data:ro" -e XVIZ_RECORD=/data/recorded "$image"
    check "convert into a read-only store: one line, no traceback" \
        refused "Read-only file system" -v "$raw:/raw:ro" -v "$work/store:/data:ro" "$image" convert kitti /raw /data/again --frames 0:2
else
    say "SKIPPED the convert service and mounted store: no KITTI excerpt at $raw"
fi

# -- ROS bags and MCAP files in the store, served as they are (the image has the ros extra)
if [ -d "$raw" ] && [ -x "$python" ]; then
    mkdir -p "$work/bags"
    # devkit/rosbag_kitti.py writes the real KITTI excerpt's first frames with rosbags' own writers.
    "$python" - "$raw" "$work/bags" <<'PY' >"$work/bags.log" 2>&1 || cat "$work/bags.log"
import pathlib, sys
from devkit.rosbag_kitti import write_bag
from xviz_server.datasets.kitti import KittiDrive
drive, out = KittiDrive(pathlib.Path(sys.argv[1])), pathlib.Path(sys.argv[2])
write_bag(out / "kitti-ros1.bag", "ros1", drive=drive, frames=5)
write_bag(out / "kitti-mcap.mcap", "mcap", drive=drive, frames=5)
PY
    chmod -R a+rX "$work/bags"
    port=$(free_port)
    start bags -p "127.0.0.1:$port:3000" -v "$work/bags:/data:ro" "$image"
    check "a store of a ROS 1 bag and an MCAP file: healthy" wait_healthy bags
    check "the bag and the MCAP file are listed" catalog_has "http://127.0.0.1:$port/" kitti-ros1 kitti-mcap
    probe_bag() { e exec "$run_id-bags" xviz-server probe --timeout 60 "ws://127.0.0.1:3000/?log=$1" >"$work/probe-$1.log" 2>&1 || { cat "$work/probe-$1.log"; return 1; }; }
    check "a client reads the ROS 1 bag, converted in the image" probe_bag kitti-ros1
    check "a client reads the MCAP file, converted in the image" probe_bag kitti-mcap
    bags_quiet() {  # no traceback, and no line about the files (a problem found in the store, a missing package)
        local out
        out=$(logs bags)
        ! grep -qE 'Traceback|rosbags|/data/kitti-' <<<"$out" || { grep -E 'Traceback|rosbags|/data/kitti-' <<<"$out"; return 1; }
    }
    check "the bags: no problem logged, no traceback" bags_quiet
else
    say "SKIPPED the ROS bag and MCAP store: no KITTI excerpt at $raw or no $python (run scripts/test.sh first)"
fi

# -- compose.yaml's `replicas` profile: Redis, three replicas, the proxy. A live feed pushed
# through the proxy (to one replica) reaches a viewer on every replica, each update once, in order.
kitti=$repo/../shared/data/kitti-2011_09_26_drive_0001-head
if [ ${#compose[@]} -eq 0 ]; then
    say "SKIPPED the replicas profile: no compose command for $engine"
elif [ ! -x "$python" ] || [ ! -d "$kitti" ]; then
    say "SKIPPED the replicas profile: no $python (run scripts/test.sh first) or no KITTI frames at $kitti"
else
    PROXY_PORT=$(free_port)
    XVIZ_INGEST_TOKEN=ci-ingest-$$
    export PROXY_PORT XVIZ_INGEST_TOKEN
    e tag "$image" xviz-server:latest  # the image compose.yaml's services run (podman: localhost/xviz-server)
    project=$run_id-replicas
    compose_up() {
        limit=300 e_compose up -d redis replica proxy >"$work/compose.log" 2>&1 || { cat "$work/compose.log"; return 1; }
    }
    check "replicas profile: Redis, the replicas and the proxy start" compose_up
    replicas=$(e ps --filter "label=com.docker.compose.project=$project" \
                    --filter label=com.docker.compose.service=replica --format '{{.Names}}' | sed "s/^$run_id-//" | sort)
    three_healthy() {
        [ "$(wc -w <<<"$replicas")" -eq 3 ] || return 1
        local name
        for name in $replicas; do wait_healthy "$name" || return 1; done
    }
    check "replicas profile: three replicas, each healthy" three_healthy
    # The source: the KITTI metadata through the proxy; once every viewer has joined, the updates at 10 Hz.
    updates=$(($(find "$kitti" -name '*-frame.glb' | wc -l) - 1))
    timeout 150 "$python" - "$PROXY_PORT" "$XVIZ_INGEST_TOKEN" "$kitti" "$work/go" >"$work/source.out" 2>&1 <<'PY' &
import asyncio, pathlib, sys
from websockets.asyncio.client import connect
async def main(port, token, folder, go):
    frames = sorted(pathlib.Path(folder).glob("*-frame.glb"), key=lambda path: int(path.name.split("-")[0]))
    async with connect(f"ws://127.0.0.1:{port}/ingest/car", additional_headers={"Authorization": f"Bearer {token}"},
                       max_size=None, open_timeout=20) as websocket:
        await websocket.send(frames[0].read_bytes())
        while not pathlib.Path(go).exists():
            await asyncio.sleep(0.1)
        for frame in frames[1:]:
            await websocket.send(frame.read_bytes())
            await asyncio.sleep(0.1)
        await asyncio.sleep(5)  # the viewers count before the source leaves
        print(len(frames) - 1, "sent", flush=True)
asyncio.run(main(*sys.argv[1:]))
PY
    source_pid=$!
    # A viewer inside each replica ($run_id-NAME), on that replica's own port: waits for the feed
    # in its catalog, joins, and counts the updates (complete states sent on joining aside).
    viewer() {
        limit=150 e exec -i "$run_id-$1" python3 - "$updates" >"$work/viewer-$1.out" 2>&1 <<'PY'
import asyncio, json, sys, urllib.request
from websockets.asyncio.client import connect
from xviz_server.codec import decode
async def main():
    while not any(feed["name"] == "car" and feed["connected"]
                  for feed in json.load(urllib.request.urlopen("http://127.0.0.1:3000/", timeout=5)).get("live", [])):
        await asyncio.sleep(0.2)
    async with connect("ws://127.0.0.1:3000/?log=car&session_type=live", max_size=None) as websocket:
        times = []
        async for data in websocket:
            message = decode(data)
            if message["type"] == "xviz/metadata":
                print("joined", flush=True)
            elif message["type"] == "xviz/state_update" and message["data"]["update_type"] != "COMPLETE_STATE":
                times.append(message["data"]["updates"][0]["timestamp"])
                if len(times) == int(sys.argv[1]):
                    break
        print("updates", len(times), "in order" if times == sorted(set(times)) else f"out of order: {times}", flush=True)
asyncio.run(asyncio.wait_for(main(), 120))
PY
    }
    viewers=()
    for name in $replicas; do viewer "$name" & viewers+=($!); done
    joined() { local name; for name in $replicas; do grep -q joined "$work/viewer-$name.out" 2>/dev/null || return 1; done; }
    deadline=$((SECONDS + 90))
    until joined || [ "$SECONDS" -ge "$deadline" ]; do sleep 0.2; done
    touch "$work/go"
    for pid in "${viewers[@]}"; do wait "$pid" || true; done
    wait "$source_pid" || true
    every_viewer() {
        [ "$(wc -w <<<"$replicas")" -eq 3 ] || return 1
        local name
        for name in $replicas; do
            grep -q "updates $updates in order" "$work/viewer-$name.out" || { cat "$work/viewer-$name.out" "$work/source.out"; return 1; }
        done
    }
    check "replicas profile: a feed pushed through the proxy reaches a viewer on every replica, all $updates updates in order" every_viewer
fi

# -- numbers ----------------------------------------------------------------------
share=${base_size:+, $(((size - base_size) / 1000000)) MB over the base}
if [ -n "$base_size" ]; then
    check "the image is at most $budget_mb MB over its base" test "$(((size - base_size) / 1000000))" -le "$budget_mb"
fi
say "image size $((size / 1000000)) MB$share, built in $build_time s, healthy $time_to_healthy s after run, stopped in $stop_time s"
if [ "$failures" -gt 0 ]; then
    say "$failures check(s) failed"
    exit 1
fi
say "all checks passed"
