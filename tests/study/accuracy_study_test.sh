#!/usr/bin/env bash
# ctest `study`: runs scripts/accuracy-study --quick into a temporary directory and checks its
# outputs: every file present and non-empty, reference rows with zero error, every error finite,
# the grasp producing contact forces, the exact compliance close to its own reference, and the
# W error ordering warped < rest < uncoupled. Haptic loop: R1 (the exact step at the tick's pose)
# replays a step exactly, R1 and R2 agree with each other's rows, the converged local model is
# closer to R1 than holding the force and renders R1's stiffness on the slow press, the
# references are passive and holding the force on a tap is not. Compliance on the same states: the
# exact model's rows have zero error, the per-state W error orders warped < rest < uncoupled, and
# the bounded warped model is the exact one where it fell back and the warped one elsewhere.
# Usage: accuracy_study_test.sh TACTUS_ACCURACY_BINARY REPO_ROOT
set -euo pipefail
bin="$1"
root="$2"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
TACTUS_ACCURACY_BIN="$bin" "$root/scripts/accuracy-study" --quick --out "$tmp/out" \
  --cache-dir "$tmp/cache"
for f in sim_accuracy.csv haptic_accuracy.csv sim_timeseries.csv haptic_timeseries.csv meta.csv \
         w_accuracy.csv w_states.csv accuracy.md accuracy_pareto.png accuracy_forces.png \
         accuracy_w_states.png; do
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
meta = {r["key"]: r["value"] for r in rows("meta.csv")}
err_cols = ["force_rel_rms", "force_peak_err_n", "max_penetration_mm", "complementarity_max_nm"]
if not sim:
    fails.append("sim: no rows")
refs = [r for r in sim if r["is_reference"] == "1"]
if not refs:
    fails.append("sim: no reference row")
for r in sim:
    for c in err_cols + ["energy_dev_rel", "nsgs_error_max"]:
        if not math.isfinite(float(r[c])):
            fails.append(f"sim: {c} not finite in {r}")
for r in refs:
    for c in ["force_rel_rms", "force_peak_err_n", "energy_dev_rel"]:
        if float(r[c]) != 0.0:
            fails.append(f"sim: reference row has {c} = {r[c]}")
    if float(r["force_ref_peak_n"]) < 0.1:
        fails.append(f"sim: the reference never pushes (peak {r['force_ref_peak_n']} N)")
if not any(float(r["force_rel_rms"]) > 0 for r in sim if r["is_reference"] == "0"):
    fails.append("sim: every variant has zero error (nothing was compared)")
exact = [r for r in sim if r["study"] == "compliance" and r["label"] == "exact"]
if not exact or float(exact[0]["force_rel_rms"]) > 0.01:
    fails.append("exact compliance at tolerance 1e-6 is not within 1 % of its reference")
# the paper's claim (eq. 12): warping C0 by the nodal rotations beats C0 alone
w = {r["compliance"]: float(r["w_rel_err_median"]) for r in rows("w_accuracy.csv")}
if not all(math.isfinite(v) for v in w.values()) or not (w["warped"] < w["rest"] < w["uncoupled"]):
    fails.append(f"W error ordering warped < rest < uncoupled violated: {w}")

# ---- compliance models on the same states
st = rows("w_states.csv")
by = {}
for r in st:
    by.setdefault(r["model"], []).append(r)
if set(by) != {"exact", "warped", "warped_bounded", "rest", "uncoupled"} or not by["exact"]:
    fails.append(f"w_states: models missing: {sorted(by)}")
else:
    def med(v):
        v = sorted(v)
        return v[len(v) // 2]
    if any(float(r["w_rel_err"]) != 0 or float(r["force_rel_err"]) != 0 for r in by["exact"]):
        fails.append("w_states: the exact model differs from itself")
    wm = {m: med([float(r["w_rel_err"]) for r in by[m]]) for m in by}
    if not wm["warped"] < wm["rest"] < wm["uncoupled"]:
        fails.append(f"w_states: per-state W error not ordered warped < rest < uncoupled: {wm}")
    for wr, br in zip(by["warped"], by["warped_bounded"]):
        if wr["t_s"] != br["t_s"]:
            fails.append("w_states: models sampled different states")
            break
        e = float(br["w_rel_err"])
        if br["exact_fallback"] == "1" and e > 1e-12:
            fails.append(f"w_states: bounded model fell back at t {br['t_s']} but W error {e}")
        if br["exact_fallback"] == "0" and abs(e - float(wr["w_rel_err"])) > 1e-9:
            fails.append(f"w_states: bounded model kept warped at t {br['t_s']} but its W differs")

# ---- haptic loop
hcols = ["err_r1_rel_rms", "err_r1_max_n", "err_r2_rel_rms", "err_r2_max_n", "stiffness_npm",
         "max_penetration_mm", "energy_to_hand_mj", "tick_us_median"]
for r in hap:
    for c in hcols:
        if not math.isfinite(float(r[c])):
            fails.append(f"haptic: {c} not finite in {r}")
    if int(r["ticks_compared"]) <= 0:
        fails.append(f"haptic: a row compared no ticks: {r}")
# R1 restored from a saved state and stepped reproduces the step it replays
if float(meta["replay_max_rel_diff"]) > 1e-6:
    fails.append(f"R1 replay differs from the run it replays: {meta['replay_max_rel_diff']}")
cases = {}
for r in hap:
    cases.setdefault((r["motion"], r["rate_hz"], r["sim_hz"], r["snapshot_w"]), {})[
        (r["method"], int(r["sweeps_per_tick"]))] = r
if {k[0] for k in cases} != {"slow_press", "tremor", "fast_tap"} or \
        {k[3] for k in cases} != {"scene", "exact"}:
    fails.append(f"haptic: motions missing: {sorted(cases)}")
def f(r, c):
    return float(r[c])
for key, m in cases.items():
    r1, r2 = m.get(("r1", 0)), m.get(("r2", 0))
    hold, conv = m.get(("hold", 0)), m.get(("local", 0))
    if not (r1 and r2 and hold and conv and ("local", 1) in m and ("coupling", 0) in m
            and ("extrapolate", 0) in m):
        fails.append(f"haptic {key}: a method is missing: {sorted(m)}")
        continue
    if f(r1, "err_r1_max_n") != 0 or f(r2, "err_r2_max_n") != 0:
        fails.append(f"haptic {key}: a reference differs from itself")
    # the decomposition's two references are compared on the same ticks both ways
    if abs(f(r1, "err_r2_max_n") - f(r2, "err_r1_max_n")) > 1e-9 * max(1.0, f(r1, "err_r2_max_n")):
        fails.append(f"haptic {key}: |R1 - R2| differs between the R1 and R2 rows")
    if f(r1, "force_r1_peak_n") < 0.1:
        fails.append(f"haptic {key}: R1 never pushes (peak {r1['force_r1_peak_n']} N)")
    # a damped tissue is passive: over a closed motion the references take energy from the hand
    for ref in (r1, r2):
        if f(ref, "energy_to_hand_mj") >= 0:
            fails.append(f"haptic {key}: {ref['method']} gives the hand energy "
                         f"({ref['energy_to_hand_mj']} mJ) over a closed motion")
    if key[0] == "slow_press":
        # the paper's claim: the local model follows the exact problem between snapshots
        if not f(conv, "err_r1_rel_rms") < f(hold, "err_r1_rel_rms"):
            fails.append(f"haptic {key}: converged local model not closer to R1 than hold: "
                         f"{conv['err_r1_rel_rms']} vs {hold['err_r1_rel_rms']}")
        # with exact-W snapshots only the linearisation is left: it must win clearly
        if key[3] == "exact" and not f(conv, "err_r1_rel_rms") < 0.5 * f(hold, "err_r1_rel_rms"):
            fails.append(f"haptic {key}: on exact-W snapshots the converged local model is not "
                         f"twice as close to R1 as hold: {conv['err_r1_rel_rms']} vs "
                         f"{hold['err_r1_rel_rms']}")
        k1 = f(conv, "stiffness_r1_npm")
        if not (k1 > 0 and abs(f(conv, "stiffness_npm") - k1) < 0.2 * k1):
            fails.append(f"haptic {key}: local model stiffness {conv['stiffness_npm']} N/m not "
                         f"within 20 % of R1's {k1}")
    if key[0] == "fast_tap" and not f(hold, "energy_to_hand_mj") > f(conv, "energy_to_hand_mj"):
        fails.append(f"haptic {key}: holding the force is not more active than the local model")
md = open(os.path.join(d, "accuracy.md")).read()
if "| study |" not in md or "| motion | method |" not in md:
    fails.append("accuracy.md lacks its tables")
for f in fails:
    print("FAIL:", f, file=sys.stderr)
sys.exit(1 if fails else 0)
PY
echo "accuracy study (quick): outputs present and consistent"
