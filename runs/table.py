# The table of a long run in docs/hard_cases.md: per block of steps, the smallest start- and
# end-of-step gaps, the largest area/volume error before correction, GMRES mean and max.
# python3 runs/table.py OBSERVABLES.csv [STEPS_PER_ROW]
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
every = int(sys.argv[2]) if len(sys.argv) > 2 else 100
print("| steps | smallest start-of-step gap | smallest end-of-step gap | largest area/volume error before correction | GMRES (mean, max) |")
print("|---|---|---|---|---|")
for a in range(0, len(rows), every):
    ch = rows[a:a+every]
    g = min(float(r['min_gap']) for r in ch)
    e = [float(r['end_gap']) for r in ch if r['end_gap']]
    err = max(float(r['area_volume_error']) for r in ch)
    gm = sum(float(r['gmres_mean']) for r in ch)/len(ch); gx = max(int(r['gmres_max']) for r in ch)
    end = f"{min(e):.5f}" if e else "–"
    print(f"| {ch[0]['step']}–{ch[-1]['step']} | {g:.4f} | {end} | {err:.1e} | {gm:.1f}, {gx} |")
