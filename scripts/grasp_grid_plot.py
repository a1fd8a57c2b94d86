#!/usr/bin/python3
"""Plot the grasp-anywhere grid: outcomes per approach and where the approaches fail.

Usage: grasp_grid_plot.py [--table] OUT.png LABEL=GRID.csv [LABEL=GRID.csv ...]

Each GRID.csv is what `pad_grasp_study --grid --csv` writes (one row per approach). One row of
two panels per file: left, each approach's held nodes' rise against the tool's and the smallest
tet volume ratio in the jaws (the goal's box shaded: rise >= 90 %, ratio >= 0.3; ratios below
the axis drawn on its floor); right, the approaches on the offset plane (the roll and the grip
shift the marker a little), filled when the approach met all three conditions. One marker per grip
(spring, and a closed handle's squeeze when the CSV has the column); red: a tet inverted somewhere. --table also prints the summary and the
per-approach table (Markdown) that docs/measurements.md quotes. Run it with /usr/bin/python3 (Debian's
python3-matplotlib); no other dependency.
"""
import argparse
import csv
import sys

RATIO_FLOOR = -0.6   # the left panels' lowest ratio; below it a point sits on the floor


def read_rows(path):
    with open(path, newline="") as f:
        rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]
    if not rows:
        sys.exit(f"{path}: no approaches")
    return rows


def grip(row):
    """The approach's grip: (spring [N m/rad], a closed handle's squeeze [N m]; 0 in CSVs from
    before the squeeze column)."""
    return (row["grip_nmprad"], row.get("grip_squeeze_nm", 0.0))


def grip_text(g):
    return f"{g[0]:g}" + (f" + {g[1]:g} N m" if g[1] > 0.0 else "")


def holds(row):
    return row["rise_pct"] >= 90.0


def met(row):
    return holds(row) and row["min_jaw_ratio"] >= 0.3 and row["inverted_steps"] == 0


def main():
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Example:\n  grasp_grid_plot.py --table grid.png liver_grasp_20k=grid_20k.csv "
               "liver_grasp_23k=grid_23k.csv")
    ap.add_argument("out")
    ap.add_argument("grids", nargs="+", help="LABEL=GRID.csv")
    ap.add_argument("--table", action="store_true", help="print the Markdown tables")
    a = ap.parse_args()
    grids = []
    for g in a.grids:
        label, sep, path = g.partition("=")
        if not sep:
            sys.exit(f"{g}: expected LABEL=GRID.csv")
        grids.append((label, read_rows(path)))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grips = sorted({grip(r) for _, rows in grids for r in rows})
    markers = ["o", "s", "^", "D"]
    fig, axes = plt.subplots(len(grids), 2, figsize=(12, 5 * len(grids)), squeeze=False)
    for (label, rows), (ax_o, ax_m) in zip(grids, axes):
        n_hold = sum(holds(r) for r in rows)
        n_met = sum(met(r) for r in rows)
        ax_o.axvspan(90.0, 110.0, ymin=0.0, ymax=1.0, color="0.93")
        ax_o.fill_between([90.0, 110.0], 0.3, 1.05, color="#c8e6c9")
        for r in rows:
            marker = markers[grips.index(grip(r)) % len(markers)]
            colour = "tab:red" if r["inverted_steps"] > 0 else "tab:blue"
            y = max(r["min_jaw_ratio"], RATIO_FLOOR)
            x = min(max(r["rise_pct"], -30.0), 110.0)
            ax_o.plot(x, y, marker, color=colour, fillstyle="full" if met(r) else "none",
                      markersize=8)
        ax_o.axhline(0.3, color="0.4", lw=0.8, ls="--")
        ax_o.axvline(90.0, color="0.4", lw=0.8, ls="--")
        ax_o.set_xlim(-32.0, 112.0)
        ax_o.set_ylim(RATIO_FLOOR - 0.05, 1.05)
        ax_o.set_xlabel("held nodes' rise / tool's rise [%] (clipped to -30..110)")
        ax_o.set_ylabel(f"smallest tet volume / rest in the jaws (floor {RATIO_FLOOR})")
        ax_o.set_title(f"{label}: {n_hold} of {len(rows)} hold, {n_met} meet all three")

        for r in rows:
            marker = markers[grips.index(grip(r)) % len(markers)]
            colour = "tab:red" if r["inverted_steps"] > 0 else "tab:blue"
            dx = 0.6 if grips.index(grip(r)) % 2 else -0.6
            dy = 0.05 * r["roll_deg"]
            ax_m.plot(r["x_mm"] + dx, r["y_mm"] + dy, marker, color=colour,
                      fillstyle="full" if met(r) else "none", markersize=9)
            ax_m.annotate(f"{r['rise_pct']:.0f}%", (r["x_mm"] + dx, r["y_mm"] + dy),
                          textcoords="offset points", xytext=(0, 7), ha="center", fontsize=6)
        ax_m.set_xticks([-5, 0, 5])
        ax_m.set_yticks([-5, 0, 5])
        ax_m.set_xlim(-7.5, 7.5)
        ax_m.set_ylim(-7.5, 7.5)
        ax_m.grid(True, lw=0.3)
        ax_m.set_xlabel("along the jaws, world x [mm] (+: backed out; shift -/+ 0.6: grip)")
        ax_m.set_ylabel("along the lobe's edge, world y [mm] (shift +1: roll +20 deg)")
        ax_m.set_title(f"{label}: approaches (label: rise)")

    handles = [plt.Line2D([], [], marker=markers[i % len(markers)], ls="", color="0.3",
                          label=f"grip {g[0]:g} N m/rad" +
                          (f" + squeeze {g[1]:g} N m" if g[1] > 0.0 else ""))
               for i, g in enumerate(grips)]
    handles += [plt.Line2D([], [], marker="o", ls="", color="tab:red", label="a tet inverted"),
                plt.Line2D([], [], marker="o", ls="", color="tab:blue", fillstyle="none",
                           label="open: fails a condition")]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles))
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(a.out, dpi=100)
    if a.table:
        print_tables(grids)


def key(r):
    return (grip(r), r["x_mm"], r["y_mm"], r["roll_deg"])


def ratio_text(ratio):
    return f"{ratio:.3f}" if ratio > -10.0 else f"{ratio:.0f}"


def print_tables(grids):
    print("| mesh | approaches | held (rise >= 90 %) | smallest tet in the jaws >= 0.3 | "
          "no tet inverted anywhere | all three | smallest tet in the jaws, min / median |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for label, rows in grids:
        n = len(rows)
        ratios = sorted(r["min_jaw_ratio"] for r in rows)

        def count(k):
            return f"{k} ({100.0 * k / n:.0f} %)"

        print(f"| {label} | {n} | {count(sum(holds(r) for r in rows))} | "
              f"{count(sum(r['min_jaw_ratio'] >= 0.3 for r in rows))} | "
              f"{count(sum(r['inverted_steps'] == 0 for r in rows))} | "
              f"{count(sum(met(r) for r in rows))} | "
              f"{ratio_text(ratios[0])} / {ratio_text(ratios[(n - 1) // 2])} |")
    print()
    labels = [label for label, _ in grids]
    by_key = [{key(r): r for r in rows} for _, rows in grids]
    keys = sorted(set().union(*[set(k) for k in by_key]))
    print("| grip [N m/rad (+ squeeze)] | x, y [mm] | roll [deg] | " +
          " | ".join(f"{label}: rise, smallest tet in the jaws, inverted steps" for label in labels)
          + " |")
    print("| --- | --- | --- | " + " | ".join("---" for _ in labels) + " |")
    for k in keys:
        cells = []
        for rows in by_key:
            r = rows.get(k)
            if r is None:
                cells.append("not run")
                continue
            mark = "**" if met(r) else ""
            cells.append(f"{mark}{r['rise_pct']:.0f} %, {ratio_text(r['min_jaw_ratio'])}, "
                         f"{int(r['inverted_steps'])}{mark}")
        print(f"| {grip_text(k[0])} | {k[1]:+g}, {k[2]:+g} | {k[3]:+g} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
