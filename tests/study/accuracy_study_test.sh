#!/usr/bin/env bash
# ctest `study`: runs scripts/accuracy-study --quick into a temporary directory and checks its
# outputs: every file present and non-empty, reference rows with zero error, every error finite,
# the grasp producing contact forces, the exact compliance close to its own reference, and the
# W error ordering warped < rest < uncoupled.
# Usage: accuracy_study_test.sh TACTUS_ACCURACY_BINARY REPO_ROOT
set -euo pipefail
bin="$1"
root="$2"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
TACTUS_ACCURACY_BIN="$bin" "$root/scripts/accuracy-study" --quick --out "$tmp/out" \
  --cache-dir "$tmp/cache"
for f in sim_accuracy.csv haptic_accuracy.csv sim_timeseries.csv haptic_timeseries.csv meta.csv \
         w_accuracy.csv accuracy.md accuracy_pareto.png accuracy_forces.png; do
  if [[ ! -s "$tmp/out/$f" ]]; then
    echo "FAIL: $f is missing or empty" >&2
    exit 1
  fi
done
/usr/bin/python3 - "$tmp/out" <<'PY'
import csv, math, os, sys
d = sys.argv[1]
fails = []
def rows(name):
    with open(os.path.join(d, name), newline="") as f:
        return list(csv.DictReader(f))
sim = rows("sim_accuracy.csv")
hap = rows("haptic_accuracy.csv")
err_cols = ["force_rel_rms", "force_peak_err_n", "max_penetration_mm", "complementarity_max_nm"]
for name, table, cols in [("sim", sim, err_cols + ["energy_dev_rel", "nsgs_error_max"]),
                          ("haptic", hap, err_cols + ["work_dev_mj"])]:
    if not table:
        fails.append(f"{name}: no rows")
    refs = [r for r in table if r["is_reference"] == "1"]
    if not refs:
        fails.append(f"{name}: no reference row")
    for r in table:
        for c in cols:
            if not math.isfinite(float(r[c])):
                fails.append(f"{name}: {c} not finite in {r}")
    for r in refs:
        for c in ["force_rel_rms", "force_peak_err_n"] + (["energy_dev_rel"] if name == "sim"
                                                           else ["work_dev_mj"]):
            if float(r[c]) != 0.0:
                fails.append(f"{name}: reference row has {c} = {r[c]}")
        if float(r["force_ref_peak_n"]) < 0.1:
            fails.append(f"{name}: the reference never pushes (peak {r['force_ref_peak_n']} N)")
    if not any(float(r["force_rel_rms"]) > 0 for r in table if r["is_reference"] == "0"):
        fails.append(f"{name}: every variant has zero error (nothing was compared)")
exact = [r for r in sim if r["study"] == "compliance" and r["label"] == "exact"]
if not exact or float(exact[0]["force_rel_rms"]) > 0.01:
    fails.append("exact compliance at tolerance 1e-6 is not within 1 % of its reference")
# the paper's claim (eq. 12): warping C0 by the nodal rotations beats C0 alone
w = {r["compliance"]: float(r["w_rel_err_median"]) for r in rows("w_accuracy.csv")}
if not all(math.isfinite(v) for v in w.values()) or not (w["warped"] < w["rest"] < w["uncoupled"]):
    fails.append(f"W error ordering warped < rest < uncoupled violated: {w}")
if any(int(r["ticks_compared"]) <= 0 for r in hap):
    fails.append("haptic: a row compared no ticks")
md = open(os.path.join(d, "accuracy.md")).read()
if "| study |" not in md or "| rate [kHz] |" not in md:
    fails.append("accuracy.md lacks its tables")
for f in fails:
    print("FAIL:", f, file=sys.stderr)
sys.exit(1 if fails else 0)
PY
echo "accuracy study (quick): outputs present and consistent"
