# Shared by the MPI scaling scripts (sourced, not run): the release build with MPI, the
# environment of the runs, and appending a table to benches/RESULTS.md.

# mpi_setup NAME THREADS OUT: check for mpirun, build, make OUT, export the run environment.
mpi_setup() {
    command -v mpirun >/dev/null || {
        echo "$1: needs mpirun (apt install openmpi-bin libopenmpi-dev libclang-dev)" >&2
        exit 1
    }
    # MOBO_BIN: a binary built elsewhere (a machine without cargo), else build one here.
    if [ -z "${MOBO_BIN:-}" ]; then
        cargo build --release --features mpi --quiet
    fi
    export MOBO_BIN=${MOBO_BIN:-target/release/mobo}
    mkdir -p "$3"
    export OMPI_MCA_btl_vader_single_copy_mechanism=none
    export RAYON_NUM_THREADS=$2
    export MOBO_OPERATOR_CACHE=${MOBO_OPERATOR_CACHE:-$PWD/target/operator-cache}
}

# machine: "DATE, CPU, N cores" for a table heading.
machine() {
    echo "$(date +%Y-%m-%d), $(lscpu | sed -n 's/^Model name: *//p' | head -1), $(nproc) cores"
}

# publish NAME HEADER TABLE RESULTS: print the table, and append it to RESULTS unless "-".
publish() {
    printf '%s\n\n%s\n' "$2" "$3"
    if [ "$4" != "-" ]; then
        printf '\n%s\n\n%s\n' "$2" "$3" >>"$4"
        echo "$1: appended to $4" >&2
    fi
}
