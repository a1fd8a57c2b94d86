#!/usr/bin/python3
"""Markdown table and plots of an accuracy study (tactus-accuracy's CSV files).

Usage: /usr/bin/python3 scripts/accuracy_report.py RESULTS_DIR

Reads sim_accuracy.csv, haptic_accuracy.csv, sim_timeseries.csv, haptic_timeseries.csv and
meta.csv from RESULTS_DIR and writes there:
  accuracy.md           the tables (simulation step; haptic local model) and the notes
  accuracy_pareto.png   force error against time per step / per tick, Pareto fronts
  accuracy_forces.png   contact force over time: compliance models; haptic models at one rate
Run it with Debian's /usr/bin/python3 (matplotlib from python3-matplotlib).
"""
import csv
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


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


def haptic_table(rows):
    out = [
        "| rate [kHz] | model | sim step [ms] | sweeps / tick | force error RMS [%] "
        "| peak error [N] (ref. peak) | max penetration [mm] | compl. residual [N m] "
        "| work dev. [mJ] (ref. work) | time per tick [us] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        kind = r["kind"]
        if kind == "reference":
            model = "**reference**: full model stepped at the tick"
            sweeps = "to tol."
        elif kind == "hold":
            model = "hold (last snapshot's force)"
            sweeps = "0"
        else:
            model = "local model (paper 4.2)"
            sweeps = r["sweeps_per_tick"]
        out.append(
            f"| {num(r, 'rate_hz') / 1000:g} | {model} | {float(r['sim_h_ms']):g} | {sweeps} "
            f"| {pct(num(r, 'force_rel_rms'))} "
            f"| {num(r, 'force_peak_err_n'):.3f} ({num(r, 'force_ref_peak_n'):.2f}) "
            f"| {num(r, 'max_penetration_mm'):.4f} | {sci(num(r, 'complementarity_max_nm'))} "
            f"| {num(r, 'work_dev_mj'):+.3f} ({num(r, 'work_ref_mj'):.3f}) "
            f"| {num(r, 'tick_us_median'):.2f} |"
        )
    return "\n".join(out)


def plot_pareto(sim_rows, hap_rows, meta, path):
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5.2))
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

    rates = sorted({num(r, "rate_hz") for r in hap_rows})
    cmap = plt.get_cmap("viridis")
    sim_hs = sorted({float(r["sim_h_ms"]) for r in hap_rows if r["kind"] != "reference"})
    markers = ["o", "s", "^", "D"]
    allpts = []
    for i, rate in enumerate(rates):
        c = cmap(i / max(1, len(rates) - 1) * 0.9)
        for k, sh in enumerate(sim_hs):
            sel = [r for r in hap_rows if num(r, "rate_hz") == rate and r["kind"] != "reference"
                   and float(r["sim_h_ms"]) == sh]
            sel.sort(key=lambda r: int(r["sweeps_per_tick"]))
            xs = [max(num(r, "tick_us_median"), 1e-2) for r in sel]
            ys = [num(r, "force_rel_rms") for r in sel]
            ax2.plot(xs, ys, marker=markers[k % len(markers)], color=c, lw=1,
                     ls="-" if k == 0 else ":",
                     label=f"{rate / 1000:g} kHz, sim step {sh:g} ms")
            for r, x, y in zip(sel, xs, ys):
                ax2.annotate(r["sweeps_per_tick"], (x, y), fontsize=6, xytext=(2, 2),
                             textcoords="offset points")
                if y > 0:
                    allpts.append((x, y))
        ref = [r for r in hap_rows if num(r, "rate_hz") == rate and r["kind"] == "reference"]
        if ref:
            ax2.axvline(1000.0 * num(ref[0], "tick_us_median") / 1000.0, color=c, lw=0.8,
                        ls="--")
    front = pareto(allpts)
    if front:
        xs, ys = zip(*front)
        ax2.step(xs, ys, where="post", color="k", lw=1, ls="--", label="Pareto front")
    ax2.set_xscale("log")
    ax2.set_yscale("log")
    ax2.set_xlabel("time per haptic tick, median [us] (dashed verticals: full model per tick)")
    ax2.set_ylabel("contact force error vs full model at the tick rate, relative RMS")
    ax2.set_title(f"(b) haptic local model, {meta.get('haptic_mesh', '?')} "
                  f"(labels: sweeps per tick, 0 = hold)", fontsize=10)
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(fontsize=7, loc="best")
    fig.suptitle(f"Tactus accuracy vs time ({meta.get('date', '')}, {meta.get('mode', '')} "
                 f"mode; {meta.get('machine', '')})", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_forces(sim_ts, hap_ts, meta, path):
    def series(rows):
        out = {}
        for r in rows:
            s = out.setdefault(r["series"], ([], []))
            s[0].append(float(r["t_s"]))
            s[1].append(math.sqrt(sum(float(r[k]) ** 2 for k in ("fx_n", "fy_n", "fz_n"))))
        return out

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 4.2))
    for name, (t, f) in series(sim_ts).items():
        ax1.plot(t, f, lw=1.6 if name == "reference" else 0.9,
                 color="k" if name == "reference" else None, label=name)
    ax1.set_xlabel("t [s]")
    ax1.set_ylabel("|contact force on the grasper| [N]")
    ax1.set_title(f"(a) compliance models, {meta.get('sim_main_mesh', '')}", fontsize=10)
    ax1.grid(True, alpha=0.3)
    ax1.legend(fontsize=7)
    for name, (t, f) in series(hap_ts).items():
        ax2.plot(t, f, lw=1.6 if name == "reference" else 0.9,
                 color="k" if name == "reference" else None, label=name)
    ax2.set_xlabel("t [s]")
    ax2.set_ylabel("|contact force| [N]")
    ax2.set_title("(b) haptic ticks at the second rate, reference = full model per tick",
                  fontsize=10)
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    sim_rows = read_csv(os.path.join(d, "sim_accuracy.csv"))
    hap_rows = read_csv(os.path.join(d, "haptic_accuracy.csv"))
    meta = {r["key"]: r["value"] for r in read_csv(os.path.join(d, "meta.csv"))}
    w_rows = read_csv(os.path.join(d, "w_accuracy.csv"))
    plot_pareto(sim_rows, hap_rows, meta, os.path.join(d, "accuracy_pareto.png"))
    plot_forces(read_csv(os.path.join(d, "sim_timeseries.csv")),
                read_csv(os.path.join(d, "haptic_timeseries.csv")), meta,
                os.path.join(d, "accuracy_forces.png"))
    t0 = float(meta["haptic_t0_s"])
    md = f"""## Accuracy against time

Generated by `scripts/accuracy-study` ({meta.get('mode')} mode, {meta.get('date')}; study took
{float(meta['total_s']):.0f} s). Machine: {meta.get('machine')}. Times are medians of
`std::chrono::steady_clock` wall time per step / per tick.

![accuracy vs time](accuracy_pareto.png)

### Simulation step

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

### Haptic local model

Window {t0:g} .. {t0 + float(meta['haptic_window_s']):g} s of the script on {meta['haptic_mesh']},
device = script + {meta['tremor_mm']} mm tremor at {meta['tremor_hz']} Hz. All runs start from
the same state (a prefix run). **Reference** at rate r: a `Simulation` with time step 1/r driven
by the device at every tick ({meta['haptic_reference_compliance']} compliance, tolerance
{float(meta['reference_tolerance']):.0e}). **Local model**: the simulation at its own step
publishes snapshot k (device x_h(t_k)); ticks in `[t_k + {meta['haptic_latency_steps']} h,
t_k + {int(meta['haptic_latency_steps']) + 1} h)` move `delta_free = delta_free* + J (x_h [-]
x_h*)` and re-solve with warm-started NSGS (tolerance {float(meta['haptic_tolerance']):.0e}, the
sweep budget, no time budget), as `HapticLoop::solveLocalModel`. **Hold**: the snapshot's force
unchanged. Penetration and complementarity are those of each tick's linearised problem
(`delta = W f + delta_free`). Work deviation: `sum F . dx_h` of the model minus the reference's
(energy the rendering adds (+) or removes). The reference's "time per tick" is its full step.

{haptic_table(hap_rows)}
"""
    with open(os.path.join(d, "accuracy.md"), "w") as f:
        f.write(md)
    print(f"wrote {os.path.join(d, 'accuracy.md')}, accuracy_pareto.png, accuracy_forces.png")


if __name__ == "__main__":
    main()
