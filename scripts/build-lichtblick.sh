#!/usr/bin/env bash
# Build Lichtblick's web app for tests/test_lichtblick.py from its source vendored in this repository
# (tests/vendor/lichtblick/: v1.10.8, MPL-2.0), as the build stage of Lichtblick's Dockerfile does:
#
#   XVIZ_LICHTBLICK_DIR=$(scripts/build-lichtblick.sh)
#
# Prints the folder of the app's static files (its `web/.webpack`) on stdout, everything else on stderr.
# The folder is kept, by commit, in ${XVIZ_LICHTBLICK_CACHE:-${XDG_CACHE_HOME:-~/.cache}/xviz-server}/
# lichtblick-9554e1e; when it is there (its `.built` file is written last) nothing is built again. A build
# runs in a temporary folder beside it, renamed into place when done, one at a time (flock).
#
# Only package registries are used, no GitHub: the source comes from the archive (checked by its SHA-256),
# yarn 3.6.3 from the npm registry through corepack, the packages from the npm registry as yarn.lock pins
# them (`yarn install --immutable`). What the source's git-lfs files would have given:
# - the fonts (without them the app waits forever for fonts that are LFS pointers): Inter from the npm
#   package inter-ui 3.19.3, byte for byte the LFS objects (checked against the pointers' SHA-256);
#   IBM Plex Mono (its LFS objects are on no registry) from @fontsource/ibm-plex-mono 5.3.0, the same
#   typeface's latin subset. Both packages are checked by their registry integrity pinned here.
# - yarn's plugins (.yarn/plugins/*.cjs, which add commands none of this uses) are left out of .yarnrc.yml.
# Electron's package would download its binary from GitHub when installed; the web build does not use
# it (ELECTRON_SKIP_BINARY_DOWNLOAD=1, electron's own switch). Needs node >= 20 with corepack, npm, xz,
# flock, about 2 GB of disk while building and webpack's 6 GB heap (the source's .yarn/yarn-wrapper.js).
set -euo pipefail
COMMIT=9554e1e429c2c6409d4ea44d2f0e3082049f82ab
NAME=lichtblick-${COMMIT:0:7}
REPO=$(cd "$(dirname "$0")/.." && pwd)
ARCHIVE=$REPO/tests/vendor/lichtblick/$NAME.tar.xz
ROOT=${XVIZ_LICHTBLICK_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/xviz-server}
DEST=$ROOT/$NAME
# name@version, the registry's integrity of its tarball
INTER=(inter-ui@3.19.3 sha512-5FG9fjuYOXocIfjzcCBhICL5cpvwEetseL3FU6tP3d6Bn7g8wODhB+I9RNGRTizCT7CUG4GOK54OPxqq3msQgg==)
PLEX=(@fontsource/ibm-plex-mono@5.3.0 sha512-eTgnZjZEGk1QtD3ZstF+Vclo2HLAni8YMy34/DxllwZvyz1lR/1RF/xTiAquOBO7MvqBx8D2Ig2WCPMVfdZu7Q==)

say() { echo "build-lichtblick: $*" >&2; }
die() {
    say "$*"
    exit 1
}
done_already() {
    if [ -f "$DEST/.built" ]; then
        say "built: export XVIZ_LICHTBLICK_DIR=$DEST"
        echo "$DEST"
        exit 0
    fi
}

done_already
for tool in node npm corepack xz flock sha256sum; do
    command -v "$tool" >/dev/null 2>&1 || die "$tool not found (needs node >= 20 with corepack, npm, xz, flock)"
done
mkdir -p "$ROOT"
exec 9>"$ROOT/$NAME.lock"
if ! flock -n 9; then
    say "waiting for another build of $NAME to finish (lock $ROOT/$NAME.lock)"
    flock 9
fi
done_already
(cd "$(dirname "$ARCHIVE")" && sha256sum --quiet -c "$NAME.tar.xz.sha256" >&2) || die "$ARCHIVE: checksum differs"
# `git archive` names the commit in the tar's first (pax) header: the one this script builds.
header=$(xz -dc "$ARCHIVE" 2>/dev/null | head -c 1024 | tr -d '\0' || true)
[[ $header == *"comment=$COMMIT"* ]] || die "$ARCHIVE is not the archive of commit $COMMIT"

WORK=$(mktemp -d "$ROOT/.$NAME.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
LOG=$ROOT/$NAME.log
: >"$LOG"
run() {
    if ! "$@" >>"$LOG" 2>&1 9>&-; then
        tail -n 60 "$LOG" >&2
        die "failed: $* (the whole log: $LOG)"
    fi
}
say "building in $WORK (log: $LOG)"
SRC=$WORK/$NAME
tar -xJf "$ARCHIVE" -C "$WORK"

# A package from the registry, checked against its pinned integrity, unpacked into $WORK/NAME@VERSION.
fetch_package() {
    local spec=$1 integrity=$2 got
    got=$(cd "$WORK" && npm pack --silent --json "$spec" | node -e \
        'const [p] = JSON.parse(require("fs").readFileSync(0, "utf8")); console.log(p.integrity, p.filename)')
    [ "${got% *}" = "$integrity" ] || die "$spec: integrity ${got% *}, expected $integrity"
    mkdir -p "$WORK/$spec"
    tar -xzf "$WORK/${got#* }" -C "$WORK/$spec" --strip-components=1
}
# Put FILE in place of the git-lfs pointer TARGET; with "exact", FILE must be the pointer's own object.
replace_pointer() {
    local target=$1 file=$2 check=${3:-} oid
    oid=$(sed -n 's/^oid sha256:\([0-9a-f]*\)$/\1/p' "$target")
    [ -n "$oid" ] || die "$target is not a git-lfs pointer"
    if [ "$check" = exact ] && [ "$(sha256sum <"$file" | cut -d' ' -f1)" != "$oid" ]; then
        die "$file is not the object of $target (sha256 $oid)"
    fi
    cp "$file" "$target"
}
fetch_package "${INTER[@]}"
fetch_package "${PLEX[@]}"
assets=$SRC/packages/suite-base/src/styles/assets
inter="$WORK/${INTER[0]}/Inter (web)"
plex=$WORK/${PLEX[0]}/files/ibm-plex-mono-latin
for face in Regular Italic Medium MediumItalic SemiBold SemiBoldItalic; do
    replace_pointer "$assets/Inter-$face.woff2" "$inter/Inter-$face.woff2" exact
done
replace_pointer "$assets/PlexMono.woff2" "$plex-400-normal.woff2"
replace_pointer "$assets/PlexMono-Italic.woff2" "$plex-400-italic.woff2"
replace_pointer "$assets/PlexMono-Bold.woff2" "$plex-700-normal.woff2"
replace_pointer "$assets/PlexMono-BoldItalic.woff2" "$plex-700-italic.woff2"
# yarn's plugins are git-lfs pointers too: take the `plugins:` list out of .yarnrc.yml.
sed -i '/^plugins:$/,/^$/d' "$SRC/.yarnrc.yml"
! grep -q 'plugins' "$SRC/.yarnrc.yml" || die "$SRC/.yarnrc.yml: plugins left"

# As the Dockerfile: corepack enable (here into a folder of the build's own), yarn install, the build.
export COREPACK_NPM_REGISTRY=${COREPACK_NPM_REGISTRY:-https://registry.npmjs.org}
export COREPACK_ENABLE_DOWNLOAD_PROMPT=0
export YARN_NPM_REGISTRY_SERVER=${YARN_NPM_REGISTRY_SERVER:-https://registry.npmjs.org}
export YARN_ENABLE_PROGRESS_BARS=0 YARN_ENABLE_TELEMETRY=0
export ELECTRON_SKIP_BINARY_DOWNLOAD=1
mkdir "$WORK/bin"
corepack enable --install-directory "$WORK/bin"
export PATH=$WORK/bin:$PATH
cd "$SRC"
say "yarn install --immutable ($(yarn --version))"
started=$SECONDS
run yarn install --immutable
say "installed in $((SECONDS - started)) s; yarn run web:build:prod"
started=$SECONDS
run yarn run web:build:prod
say "built in $((SECONDS - started)) s"
[ -f web/.webpack/index.html ] || die "no web/.webpack/index.html after the build"
printf 'commit %s\nnode %s\nfonts %s %s\n' "$COMMIT" "$(node --version)" "${INTER[0]}" "${PLEX[0]}" \
    >web/.webpack/.built
rm -rf "$DEST"
mv web/.webpack "$DEST"
say "built: export XVIZ_LICHTBLICK_DIR=$DEST"
echo "$DEST"
