#!/usr/bin/python3
"""Markdown table and plots of an accuracy study (tactus-accuracy's CSV files).

Usage: /usr/bin/python3 scripts/accuracy_report.py RESULTS_DIR

Reads sim_accuracy.csv, haptic_accuracy.csv, sim_timeseries.csv, haptic_timeseries.csv and
meta.csv from RESULTS_DIR and writes there:
  accuracy.md           the tables (simulation step; haptic local model) and the notes
  accuracy_pareto.png   force error against time per step / per tick, Pareto fronts
  accuracy_forces.png   contact force over time: compliance models; haptic models at one rate
Run it with Debian's /usr/bin/python3 (matplotlib from python3-matplotlib).

Example (scripts/accuracy-study runs it on its --out folder):
  accuracy_report.py results/accuracy
"""
import csv
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from accuracy_report_states import plot_states, states_section  # noqa: E402


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def num(row, key):
    return float(row[key])


def pct(x):
    return f"{100.0 * x:.3g}"


def sci(x):
    return "0" if x == 0 else f"{x:.2g}"


def pareto(points):
    """Non-dominated (time, error) points, sorted by time."""
    front = []
    best = math.inf
    for t, e in sorted(points):
        if e < best:
            front.append((t, e))
            best = e
    return front


STUDY_TITLES = {
    "compliance": "compliance model",
    "tolerance": "NSGS tolerance (warped)",
    "sweeps": "NSGS sweep budget (warped)",
    "time_step": "time step",
}


def sim_table(rows, early):
    out = [
        f"| study | variant | mesh (tets) | h [ms] | force error RMS [%] whole / t <= {early:g} s "
        "| peak error [N] (ref. peak) | max penetration [mm] | compl. residual [N m] "
        "| NSGS error max | energy dev. [%] | step [ms] | update_compliance + build_w [ms] | solve_contacts [ms] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        label = r["label"]
        if r["is_reference"] == "1":
            label = f"**reference** ({r['compliance']}, tol {float(r['nsgs_tol']):.0e})"
        out.append(
            f"| {STUDY_TITLES.get(r['study'], r['study'])} | {label} | {r['mesh']} ({r['tets']}) "
            f"| {float(r['h_ms']):g} | {pct(num(r, 'force_rel_rms'))} / "
            f"{pct(num(r, 'force_rel_rms_early'))} "
            f"| {num(r, 'force_peak_err_n'):.3f} ({num(r, 'force_ref_peak_n'):.2f}) "
            f"| {num(r, 'max_penetration_mm'):.3f} | {sci(num(r, 'complementarity_max_nm'))} "
            f"| {sci(num(r, 'nsgs_error_max'))} | {pct(num(r, 'energy_dev_rel'))} "
            f"| {num(r, 'step_ms_median'):.2f} | {num(r, 'update_compliance_build_w_ms_median'):.3f} "
            f"| {num(r, 'solve_contacts_ms_median'):.3f} |"
        )
    return "\n".join(out)


def w_table(rows):
    out = [
        "| mesh (tets) | compliance | W error median [%] | W error max [%] | states |",
        "|---|---|---|---|---|",
    ]
    order = {"warped": 0, "rest": 1, "uncoupled": 2}
    for r in sorted(rows, key=lambda r: (int(r["tets"]), order.get(r["compliance"], 9))):
        out.append(f"| {r['mesh']} ({r['tets']}) | {r['compliance']} "
                   f"| {pct(num(r, 'w_rel_err_median'))} | {pct(num(r, 'w_rel_err_max'))} "
                   f"| {r['samples']} |")
    return "\n".join(out)


METHOD_ORDER = {"r1": 0, "r2": 1, "hold": 2, "extrapolate": 3, "coupling": 4, "local": 5,
                "linearized": 6}
METHOD_COLORS = {"r1": "k", "r2": "tab:gray", "hold": "tab:red", "extrapolate": "tab:orange",
                 "coupling": "tab:purple", "local": "tab:blue", "linearized": "tab:olive"}
MOTION_MARKERS = {"slow_press": "o", "tremor": "s", "fast_tap": "^"}


def method_key(r):
    sweeps = int(r["sweeps_per_tick"])
    return (METHOD_ORDER.get(r["method"], 9), sweeps if sweeps > 0 else 10 ** 6)


def is_main(r, meta):
    return (num(r, "rate_hz") == float(meta["haptic_rate_hz"])
            and abs(num(r, "sim_hz") - float(meta["haptic_sim_hz"])) < 1e-6)


def haptic_table(rows, meta):
    out = [
        "| motion | method | error vs R1 RMS [%] / max [N] | error vs R2 RMS [%] / max [N] "
        "| stiffness felt [N/m] (R1's) | max penetration [mm] | energy into the hand [mJ] "
        "| time per tick [us] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted([r for r in rows if is_main(r, meta)],
                    key=lambda r: (r["motion"], r.get("snapshot_w") != "scene",
                                   method_key(r))):
        label = r["label"]
        if r["method"] in ("r1", "r2"):
            label = f"**{label}**"
        if r.get("snapshot_w") == "exact":
            label += " [exact-W snapshots]"
        out.append(
            f"| {r['motion']} | {label} "
            f"| {pct(num(r, 'err_r1_rel_rms'))} / {num(r, 'err_r1_max_n'):.3f} "
            f"| {pct(num(r, 'err_r2_rel_rms'))} / {num(r, 'err_r2_max_n'):.3f} "
            f"| {num(r, 'stiffness_npm'):.0f} ({num(r, 'stiffness_r1_npm'):.0f}) "
            f"| {num(r, 'max_penetration_mm'):.2g} | {num(r, 'energy_to_hand_mj'):+.3f} "
            f"| {num(r, 'tick_us_median'):.3g} |")
    return "\n".join(out)


def rates_table(rows):
    """Error vs R1 / vs R2 of the main methods at every (haptic rate, simulation rate)."""
    shown = [("r2", 0, "R2"), ("hold", 0, "hold"), ("extrapolate", 0, "extrapolate"),
             ("coupling", 0, "coupling"), ("local", 1, "local 1 sweep"),
             ("local", 0, "local converged")]
    head = "| motion | haptic [kHz] | simulation [Hz] | " + " | ".join(
        f"{lab} vs R1 / R2 [%]" for _, _, lab in shown) + " |"
    out = [head, "|" + "---|" * (3 + len(shown))]
    cases = sorted({(r["motion"], num(r, "rate_hz"), num(r, "sim_hz"), r["snapshot_w"])
                    for r in rows})
    for motion, rate, sim_hz, snap in cases:
        sel = [r for r in rows if r["motion"] == motion and num(r, "rate_hz") == rate
               and num(r, "sim_hz") == sim_hz and r["snapshot_w"] == snap]
        cells = []
        for method, sweeps, _ in shown:
            m = [r for r in sel if r["method"] == method and int(r["sweeps_per_tick"]) == sweeps]
            cells.append(f"{pct(num(m[0], 'err_r1_rel_rms'))} / {pct(num(m[0], 'err_r2_rel_rms'))}"
                         if m else "-")
        out.append(f"| {motion} | {rate / 1000:g} | {sim_hz:g}"
                   f"{' (exact-W snapshots)' if snap == 'exact' else ''} | "
                   + " | ".join(cells) + " |")
    return "\n".join(out)


def plot_haptic_pareto(ax, rows, key, title):
    seen = set()
    for r in rows:
        if r["method"] == key[-2:] or num(r, f"{key}_rel_rms") <= 0:
            continue
        c = METHOD_COLORS.get(r["method"], "gray")
        sweeps = int(r["sweeps_per_tick"])
        lab_key = (r["method"], r["motion"])
        lab = None
        if lab_key not in seen:
            seen.add(lab_key)
            lab = f"{r['method']}, {r['motion']}"
        alpha = 1.0 if r.get("_main") else 0.35
        hollow = r.get("snapshot_w") == "exact"
        ax.scatter([max(num(r, "tick_us_median"), 1e-2)], [num(r, f"{key}_rel_rms")], s=30,
                   facecolors="none" if hollow else c, edgecolors=c,
                   marker=MOTION_MARKERS.get(r["motion"], "x"), alpha=alpha, label=lab, zorder=3)
        if r.get("_main") and r["method"] == "local":
            ax.annotate("conv." if sweeps <= 0 else str(sweeps),
                        (max(num(r, "tick_us_median"), 1e-2), num(r, f"{key}_rel_rms")),
                        fontsize=6, xytext=(2, 2), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per haptic tick, median [us] (R1, R2: the full step)")
    ax.set_ylabel(f"force error vs {key[-2:].upper()}, relative RMS")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=5, loc="best", ncol=2)


def plot_pareto(sim_rows, hap_rows, meta, path):
    fig, axes = plt.subplots(1, 3 if sim_rows else 2, figsize=(19 if sim_rows else 13, 5.4))
    if sim_rows:
        ax1 = axes[0]
        plot_sim_pareto(ax1, sim_rows, meta)
    for r in hap_rows:
        r["_main"] = is_main(r, meta)
    main = f"{float(meta['haptic_rate_hz']) / 1000:g} kHz / {float(meta['haptic_sim_hz']):g} Hz"
    plot_haptic_pareto(axes[-2], hap_rows, "err_r1",
                       f"(b) haptic methods vs R1 (the exact step at the tick's pose), "
                       f"{meta.get('haptic_mesh')}; solid: {main}", )
    plot_haptic_pareto(axes[-1], hap_rows, "err_r2",
                       "(c) haptic methods vs R2 (the full model at the haptic rate); "
                       "hollow: exact-W snapshots")
    fig.suptitle(f"Tactus accuracy vs time ({meta.get('date', '')}, {meta.get('mode', '')} "
                 f"mode; {meta.get('machine', '')})", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_sim_pareto(ax1, sim_rows, meta):
    colors = {"compliance": "tab:blue", "tolerance": "tab:orange", "sweeps": "tab:green",
              "time_step": "tab:purple"}
    main_mesh = meta.get("sim_main_mesh", "")
    pts = []
    seen = set()
    for r in sim_rows:
        err = num(r, "force_rel_rms_early")
        if r["is_reference"] == "1" or err <= 0:
            continue
        # the compliance study of the other meshes is drawn hollow
        other_mesh = r["mesh"] != main_mesh
        t = num(r, "step_ms_median")
        c = colors.get(r["study"], "gray")
        key = (r["study"], other_mesh)
        lab = None
        if key not in seen:
            seen.add(key)
            lab = STUDY_TITLES.get(r["study"], r["study"]) + (
                f" ({r['mesh']})" if other_mesh else "")
        ax1.scatter([t], [err], s=36, color=c if not other_mesh else "none", edgecolors=c,
                    label=lab, zorder=3)
        text = r["label"] if not other_mesh else f"{r['label']} ({r['mesh']})"
        ax1.annotate(text, (t, err), fontsize=7, xytext=(3, 2), textcoords="offset points")
        if r["study"] != "time_step" and not other_mesh:
            pts.append((t, err))
    front = pareto(pts)
    if front:
        xs, ys = zip(*front)
        ax1.step(xs, ys, where="post", color="k", lw=1, ls="--", label="Pareto front", zorder=2)
    ax1.set_xscale("log")
    ax1.set_yscale("log")
    ax1.set_xlabel("time per simulation step, median [ms]")
    ax1.set_ylabel(f"contact force error, relative RMS, t <= {meta.get('early_until_s')} s")
    ax1.set_title(f"(a) simulation step vs exact/tight reference ({main_mesh}, "
                  f"{meta.get('sim_duration_s', '?')} s script)", fontsize=10)
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=7, loc="best")


def force_series(rows):
    out = {}
    for r in rows:
        s = out.setdefault(r["series"], ([], []))
        s[0].append(float(r["t_s"]))
        s[1].append(math.sqrt(sum(float(r[k]) ** 2 for k in ("fx_n", "fy_n", "fz_n"))))
    return out


def plot_forces(sim_ts, hap_ts, meta, path):
    fig, axes = plt.subplots(1, 3 if sim_ts else 2, figsize=(19 if sim_ts else 13, 4.4),
                             squeeze=False)
    axes = axes[0]
    if sim_ts:
        ax1 = axes[0]
        for name, (t, f) in force_series(sim_ts).items():
            ax1.plot(t, f, lw=1.6 if name == "reference" else 0.9,
                     color="k" if name == "reference" else None, label=name)
        ax1.set_xlabel("t [s]")
        ax1.set_ylabel("|contact force on the grasper| [N]")
        ax1.set_title(f"(a) compliance models, {meta.get('sim_main_mesh', '')}", fontsize=10)
        ax1.grid(True, alpha=0.3)
        ax1.legend(fontsize=7)
    styles = {"R1": ("k", 2.0, "-"), "R2": ("tab:gray", 1.6, "--"),
              "hold the snapshot's force": ("tab:red", 1.0, "-"),
              "linear extrapolation of the force": ("tab:orange", 0.8, ":"),
              "local model converged": ("tab:blue", 1.2, "-"),
              "local model 1 sweep": ("tab:cyan", 0.8, "-.")}
    for ax2, snap, tag in [(axes[-2], "exact", "(b)"), (axes[-1], "scene", "(c)")]:
        tap = [r for r in hap_ts if r["motion"] == "fast_tap" and r.get("snapshot_w") == snap]
        for name, (t, f) in force_series(tap).items():
            if name.startswith("virtual coupling"):
                ax2.plot(t, f, lw=0.8, color="tab:purple", ls=":", label=name)
            elif name in styles:
                c, lw, ls = styles[name]
                ax2.plot(t, f, lw=lw, color=c, ls=ls, label=name)
        ax2.set_xlabel("t [s]")
        ax2.set_ylabel("|contact force on the grasper| [N]")
        ax2.set_title(f"{tag} fast tap (2 mm, 60 ms), {float(meta['haptic_rate_hz']) / 1000:g} kHz"
                      f" / {float(meta['haptic_sim_hz']):g} Hz, {meta.get('haptic_mesh')}, "
                      f"{'exact-W' if snap == 'exact' else 'scene-W'} snapshots", fontsize=9)
        ax2.grid(True, alpha=0.3)
        ax2.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def read_optional(d, name):
    path = os.path.join(d, name)
    return read_csv(path) if os.path.exists(path) else []


def sim_section(sim_rows, w_rows, meta):
    if not sim_rows:
        return ""
    return f"""### Simulation step

Every run follows the scene's scripted grasper for {meta['sim_duration_s']} s. Errors are against
a reference run in the same study: **exact** compliance and NSGS tolerance
{float(meta['reference_tolerance']):.0e} (at most {meta['reference_max_sweeps']} sweeps) at the
scene's time step; the time-step rows use the exact reference at the finest step. Force error:
contact force on the instrument, `sqrt(sum |F - F_ref|^2 / sum |F_ref|^2)` over the reference's
samples, for the whole script and for t <= {meta['early_until_s']} s (approach, closing, start of
the lift: before a run's grasp may slip, which makes the whole-script error a yes/no on the
slip), and the peak `max |F - F_ref|` (whole script). The plot uses the second window.
Max penetration: `-geometricMinGap()` after each step
(a fresh collision query). Complementarity residual: `max |f_n delta_n|` after the correction.
Energy deviation: `max |E - E_ref|` over the range of `E_ref` (kinetic + elastic + gravity).
Variants use the scene's tolerance {float(meta['scene_tolerance']):.0e} and
{meta['scene_max_sweeps']} sweeps unless the row varies them; the sweep rows use tolerance 1e-12
so that the budget binds.

{sim_table(sim_rows, float(meta['early_until_s']))}

Compliance alone, free of trajectory divergence: along each mesh's exact reference run (every
0.1 s in contact), W = H C H^T of each approximate model on the same rows (x, y, z at the 24
free surface nodes nearest the instrument) against the exact W, `||W - W_exact||_F /
||W_exact||_F`.

{w_table(w_rows)}
"""


def haptic_section(hap_rows, meta):
    lat = int(meta["haptic_latency_steps"])
    return f"""### Haptic loop

All runs start from the same state: the scene's script up to t0 = {float(meta['haptic_t0_s']):g} s
on {meta['haptic_mesh']} (the jaws on the lobe). The device then makes a closed motion around the
scripted pose at t0 (0.1 s still first): **slow_press** (raised cosine into the tissue and back),
**tremor** ({meta['tremor_mm']} mm at {meta['tremor_hz']} Hz, oblique, whole cycles),
**fast_tap** (2 mm in and out in 60 ms). Presses go against the contact force at t0.

Two references, both computed in this run:
* **R1**, the local model's own error: at every tick, the state the simulation started the step
  of the serving snapshot from is restored into an exact simulation (exact W, CHOLMOD, NSGS
  tolerance {float(meta['reference_tolerance']):.0e}), which takes one full step (collision redone,
  contact passes) at the simulation's time step with the tick's device pose. The saved state is
  not advanced. (Replay check: the same restore-and-step on {meta['replay_steps']} steps of an
  exact run reproduces its forces to {float(meta['replay_max_rel_diff']):.1e} relative.)
* **R2**, the time step's: the full model stepped at the haptic rate.

The multi-rate simulation ({meta['haptic_mesh']}'s scene compliance and solver) publishes
snapshot k (device x_h(t_k)), used by the ticks of `[t_k + {lat} h, t_k + {lat + 1} h)`.
Methods: **hold** the snapshot's force; **extrapolate** `F_k + (F_k - F_k-1)(t - t_k)/h`;
**virtual coupling**: a spring-damper to the snapshot's god object at the scene's coupling gains,
re-evaluated every tick (the CHAI3D-style proxy); **local model** (paper 4.2,
`HapticLoop::solveLocalModel`): `delta_free = delta_free* + J (x_h [-] x_h*)`, warm-started NSGS
with 1, 3, 10 sweeps (tolerance {float(meta['haptic_tolerance']):.0e}) or converged (tolerance
{float(meta['reference_tolerance']):.0e}).

Measures over the ticks every method has: force error (relative RMS and max) against R1 and R2;
**stiffness felt** within a snapshot period (least-squares slope `-dF . dx / |dx|^2` of the force
change against the device's displacement since the period's first tick, median over periods;
R1's on the same periods in brackets); **penetration** of the rendered tool's linearised problem
(hold and extrapolation: the held forces at the device pose; virtual coupling: at the god
object's pose); **energy into the hand** `sum F . dx_h` over the closed motion (> 0: the
rendering is active, it gives the hand energy); time per tick (R1, R2: the full step).
Rows marked *exact-W snapshots* run the multi-rate simulation with the exact compliance instead
of the scene's {meta['haptic_mesh']} model (its own R1, same R2): what is left against R1 is the
local model's linearisation alone.

At {float(meta['haptic_rate_hz']) / 1000:g} kHz with the simulation at {float(meta['haptic_sim_hz']):g} Hz:

{haptic_table(hap_rows, meta)}

Every rate (force error RMS against R1 / against R2):

{rates_table(hap_rows)}
"""


def main():
    if len(sys.argv) == 2 and sys.argv[1] in ("-h", "--help"):
        print(__doc__.strip())
        return
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    sim_rows = read_optional(d, "sim_accuracy.csv")
    hap_rows = read_optional(d, "haptic_accuracy.csv")
    meta = {r["key"]: r["value"] for r in read_csv(os.path.join(d, "meta.csv"))}
    w_rows = read_optional(d, "w_accuracy.csv")
    state_rows = read_optional(d, "w_states.csv")
    if state_rows:
        plot_states(state_rows, meta, os.path.join(d, "accuracy_w_states.png"))
    if hap_rows:
        plot_pareto(sim_rows, hap_rows, meta, os.path.join(d, "accuracy_pareto.png"))
        plot_forces(read_optional(d, "sim_timeseries.csv"),
                    read_csv(os.path.join(d, "haptic_timeseries.csv")), meta,
                    os.path.join(d, "accuracy_forces.png"))
    md = f"""## Accuracy against time

Generated by `scripts/accuracy-study` ({meta.get('mode')} mode, {meta.get('date')}; study took
{float(meta['total_s']):.0f} s). Machine: {meta.get('machine')}. Times are medians of
`std::chrono::steady_clock` wall time per step / per tick.

![accuracy vs time](accuracy_pareto.png)

![force of a tap](accuracy_forces.png)

{sim_section(sim_rows, w_rows, meta)}
{states_section(state_rows, meta)}
{haptic_section(hap_rows, meta) if hap_rows else ""}
"""
    with open(os.path.join(d, "accuracy.md"), "w") as f:
        f.write(md)
    print(f"wrote {os.path.join(d, 'accuracy.md')}, accuracy_pareto.png, accuracy_forces.png")


if __name__ == "__main__":
    main()
