# Shared by the scripts that run examples/scenes/rbc_shear_bie_and_dpd.toml in variants
# (dpd_vs_bie_rbc.sh, dpd_vs_bie_rbc_turned.sh, dpd_vs_bie_rbc_fold.sh): sourced from the
# repository root. Builds the sampling example, makes a temporary directory `$tmp` (removed on
# exit) and defines the scene's variants as filters.
cargo build --release --example shear_both_ways >&2
scene=examples/scenes/rbc_shear_bie_and_dpd.toml
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# The scene turned by $1 degrees about x (default 90: the cell's axis in the shear plane), run
# to 125 000 DPD steps and t_end = 40.
turned() {
    sed "s/^radius = 1.0/radius = 1.0\norientation = [1, 0, 0, ${1:-90}]/; s/^steps = 60000/steps = 125000/; s/^t_end = 4.0/t_end = 40.0/" "$scene"
}

# Filter: the DPD walls $1 apart (the box 2 higher) sliding at the same nominal shear rate.
widen() {
    local box speed
    box=$(python3 -c "print(float($1 + 2))")
    speed=$(python3 -c "print(round(1.18 * $1 / 20, 2))")
    sed "s/^box = \[20.0, 14.0, 22.0\]/box = [20.0, 14.0, $box]/; s/gap = 20.0/gap = $1.0/; s/^wall_speed = 1.18/wall_speed = $speed/"
}

# Filter: the DPD cell's local area penalty k_d set to $1 (Fedosov's default is 100).
local_area() {
    sed "s/^gamma_c = 0.0/gamma_c = 0.0\nkd = $1/"
}

# The first line of a script's output: its name $1, the date and the machine.
header() {
    echo "# $1 $(date -u +%Y-%m-%d), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
}

# Run the DPD scene "$tmp/$1.toml" (one thread, a sample every 100 steps from strain 4) into
# "$tmp/$1.txt".
run_dpd() {
    RAYON_NUM_THREADS=1 ./target/release/examples/shear_both_ways "$tmp/$1.toml" dpd 100 4 > "$tmp/$1.txt"
}

# Print the samples "$tmp/NAME.txt" of each NAME after $1, each under a heading "## $1NAME".
print_runs() {
    local prefix=$1 f
    shift
    for f in "$@"; do
        echo "## $prefix$f: t strain D inclination tank_treading_rate/shear_rate shear_rate |n.vorticity|"
        cat "$tmp/$f.txt"
    done
}
