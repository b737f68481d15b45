#!/usr/bin/env bash
# Runs the whole default test suite (unit, integration, property and doc tests).
# Long studies (accuracy tables, scaling) are #[ignore]d; run them with
#   cargo test --release -- --ignored
#
# The suite runs with --all-features, so the system libraries of the features are installed
# first when missing (as root, with apt-get); otherwise it stops and says what to install.
#   hdf5: libhdf5-dev, pkg-config; the report plots: fonts-dejavu-core
# MOBO_DEPS_ONLY=1 installs/checks the system libraries and exits (used by .ci/run before clippy).
set -euo pipefail
cd "$(dirname "$0")/.."

system_deps() {
    if command -v pkg-config >/dev/null 2>&1 && pkg-config --exists hdf5; then
        return 0
    fi
    local pkgs="libhdf5-dev pkg-config"
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "scripts/test.sh: installing $pkgs (needed by the hdf5 feature)" >&2
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $pkgs >&2
    else
        echo "scripts/test.sh: the hdf5 feature (tested with --all-features) needs the HDF5 library" >&2
        echo "  and pkg-config, which are missing; install them, e.g. as root:" >&2
        echo "  apt-get update && apt-get install -y $pkgs" >&2
        exit 1
    fi
}

fonts() {
    # The accuracy report's PNG (tests/report.rs) draws text with a TrueType font found at run
    # time (src/report/plot.rs): DejaVu from Debian when no usable font is there.
    for f in /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf /usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf; do
        [ -e "$f" ] && return 0
    done
    [ -n "${MOBO_FONT:-}" ] && [ -e "$MOBO_FONT" ] && return 0
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "scripts/test.sh: installing fonts-dejavu-core (the accuracy report's plots)" >&2
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends fonts-dejavu-core >&2
    else
        echo "scripts/test.sh: no TrueType font for the report plots; install fonts-dejavu-core" >&2
        echo "  or set MOBO_FONT to a .ttf file" >&2
        exit 1
    fi
}

system_deps
fonts
if [ "${MOBO_DEPS_ONLY:-0}" = 1 ]; then
    exit 0
fi
cargo test --all-features "$@"
