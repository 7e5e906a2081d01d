#!/usr/bin/env bash
# Build Lichtblick's web app for tests/test_lichtblick.py, as Lichtblick's Dockerfile's build stage does:
#
#   scripts/build-lichtblick.sh [DIR]        (default DIR: ./lichtblick)
#   export XVIZ_LICHTBLICK_DIR=DIR/web/.webpack
#
# It clones https://github.com/lichtblick-suite/lichtblick at the pinned commit below (v1.10.8) with its
# git-lfs files (the fonts: without them the app waits forever for fonts that are LFS pointers), then runs
# `corepack enable`, `yarn install --immutable` and `yarn run web:build:prod`. Needs git, git-lfs and node
# (the Dockerfile builds with node 16), GitHub and the npm registry, and a few GB of memory and disk; the
# test machines have no GitHub, so it does not run there (nor in CI): their build was made from the same
# commit's source by hand.
set -euo pipefail
COMMIT=9554e1e429c2c6409d4ea44d2f0e3082049f82ab
DIR=${1:-lichtblick}
if [ ! -d "$DIR/.git" ]; then
    git clone --filter=blob:none --no-checkout https://github.com/lichtblick-suite/lichtblick "$DIR"
fi
cd "$DIR"
git lfs install --local
git checkout --force "$COMMIT"
git lfs pull
corepack enable
yarn install --immutable
yarn run web:build:prod
echo "export XVIZ_LICHTBLICK_DIR=$PWD/web/.webpack"
