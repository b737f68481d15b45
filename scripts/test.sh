#!/usr/bin/env bash
# Runs the whole default test suite (unit, integration, property and doc tests).
# Long studies (accuracy tables, scaling) are #[ignore]d; run them with
#   cargo test --release -- --ignored
#
# The suite runs with --all-features, so the system libraries of the features are installed
# first when missing (as root, with apt-get); otherwise it stops and says what to install.
#   hdf5: libhdf5-dev, pkg-config; mpi: libopenmpi-dev, openmpi-bin, libclang-dev,
#   openssh-client; gpu: mesa-vulkan-drivers, libvulkan1 (lavapipe: a Vulkan adapter on the CPU,
#   so tests/gpu.rs runs the GPU kernels without a GPU; with CI=true a missing adapter fails);
#   the report plots: fonts-dejavu-core
# MOBO_DEPS_ONLY=1 installs/checks the system libraries and exits (used by .ci/run before clippy).
set -euo pipefail
cd "$(dirname "$0")/.."

# Debian packages the features need that are missing here.
missing_pkgs() {
    local pkgs=""
    # hdf5
    if ! { command -v pkg-config >/dev/null 2>&1 && pkg-config --exists hdf5; }; then
        pkgs="$pkgs libhdf5-dev pkg-config"
    fi
    # mpi: rsmpi builds against the MPI compiler wrapper, generates its bindings with
    # libclang, and the tests launch ranks with mpirun.
    if ! command -v mpicc >/dev/null 2>&1 || ! command -v mpirun >/dev/null 2>&1; then
        pkgs="$pkgs libopenmpi-dev openmpi-bin"
    fi
    # OpenMPI 4's launcher wants an ssh agent on the PATH even for ranks on this machine.
    if ! command -v ssh >/dev/null 2>&1; then
        pkgs="$pkgs openssh-client"
    fi
    # (libclang itself: libclang-cpp, which some images carry alone, is not what bindgen loads.)
    if ! ls /usr/lib/llvm-*/lib/libclang.so* /usr/lib/*/libclang.so* /usr/lib/*/libclang-[0-9]*.so* >/dev/null 2>&1; then
        pkgs="$pkgs libclang-dev"
    fi
    # gpu: the Vulkan loader and Mesa's drivers (lavapipe where there is no GPU).
    if ! ls /usr/lib/*/libvulkan.so.1 >/dev/null 2>&1; then
        pkgs="$pkgs libvulkan1"
    fi
    if ! ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1; then
        pkgs="$pkgs mesa-vulkan-drivers"
    fi
    echo "$pkgs"
}

system_deps() {
    local pkgs
    pkgs="$(missing_pkgs)"
    [ -z "$pkgs" ] && return 0
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "scripts/test.sh: installing$pkgs (needed by the hdf5, mpi and gpu features)" >&2
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $pkgs >&2
    else
        echo "scripts/test.sh: the hdf5, mpi and gpu features (tested with --all-features) need" >&2
        echo "  system libraries that are missing; install them, e.g. as root:" >&2
        echo "  apt-get update && apt-get install -y$pkgs" >&2
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
# The KIFMM fits (truncated SVDs, a minute each at 9 digits for Stokes) are computed once and
# shared by the test binaries and their MPI ranks (src/fmm/fit_cache.rs).
export MOBO_OPERATOR_CACHE="${MOBO_OPERATOR_CACHE:-$PWD/target/operator-cache}"
# wgpu: Vulkan only (skips probing GL); lavapipe needs no display but wants a runtime dir.
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
cargo test --all-features "$@"
