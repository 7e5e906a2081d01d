# Sourced by the other scripts: create .venv if needed and activate it.
# On Debian, python3 may lack ensurepip; install python3-venv then.
if [ ! -x .venv/bin/python ]; then
    if ! python3 -m venv .venv 2>/dev/null; then
        rm -rf .venv
        echo "python3 -m venv failed; installing Debian's python3-venv" >&2
        SUDO=$([ "$(id -u)" -eq 0 ] || echo sudo)
        $SUDO apt-get update -qq && $SUDO apt-get install -y -qq python3-venv
        python3 -m venv .venv
    fi
fi
# shellcheck disable=SC1091
source .venv/bin/activate
