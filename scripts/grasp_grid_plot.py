#!/usr/bin/python3
"""Plot the grasp-anywhere grid: outcomes per approach and where the approaches fail.

Usage: grasp_grid_plot.py OUT.png LABEL=GRID.csv [LABEL=GRID.csv ...]

Each GRID.csv is what `pad_grasp_study --grid --csv` writes (one row per approach). One row of
two panels per file: left, each approach's held nodes' rise against the tool's and the smallest
tet volume ratio in the jaws (the goal's box shaded: rise >= 90 %, ratio >= 0.3; ratios below
the axis drawn on its floor); right, the approaches on the offset plane (the roll shifts the
marker a little), filled when the approach met all three conditions. Circles: the scenes' grip,
squares: the firm one; red: a tet inverted somewhere. Run it with /usr/bin/python3 (Debian's
python3-matplotlib); no other dependency.
"""
import argparse
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

RATIO_FLOOR = -0.6   # the left panels' lowest ratio; below it a point sits on the floor


def read_rows(path):
    with open(path, newline="") as f:
        rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]
    if not rows:
        sys.exit(f"{path}: no approaches")
    return rows


def holds(row):
    return row["rise_pct"] >= 90.0


def met(row):
    return holds(row) and row["min_jaw_ratio"] >= 0.3 and row["inverted_steps"] == 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("grids", nargs="+", help="LABEL=GRID.csv")
    a = ap.parse_args()
    grids = []
    for g in a.grids:
        label, sep, path = g.partition("=")
        if not sep:
            sys.exit(f"{g}: expected LABEL=GRID.csv")
        grids.append((label, read_rows(path)))

    grips = sorted({r["grip_nmprad"] for _, rows in grids for r in rows})
    markers = ["o", "s", "^", "D"]
    fig, axes = plt.subplots(len(grids), 2, figsize=(12, 5 * len(grids)), squeeze=False)
    for (label, rows), (ax_o, ax_m) in zip(grids, axes):
        n_hold = sum(holds(r) for r in rows)
        n_met = sum(met(r) for r in rows)
        ax_o.axvspan(90.0, 110.0, ymin=0.0, ymax=1.0, color="0.93")
        ax_o.fill_between([90.0, 110.0], 0.3, 1.05, color="#c8e6c9")
        for r in rows:
            marker = markers[grips.index(r["grip_nmprad"]) % len(markers)]
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
            marker = markers[grips.index(r["grip_nmprad"]) % len(markers)]
            colour = "tab:red" if r["inverted_steps"] > 0 else "tab:blue"
            dx = 0.04 * r["roll_deg"] + (0.35 if grips.index(r["grip_nmprad"]) else -0.35)
            ax_m.plot(r["x_mm"] + dx, r["y_mm"], marker, color=colour,
                      fillstyle="full" if met(r) else "none", markersize=9)
            ax_m.annotate(f"{r['rise_pct']:.0f}%", (r["x_mm"] + dx, r["y_mm"]),
                          textcoords="offset points", xytext=(0, 7), ha="center", fontsize=6)
        ax_m.set_xticks([-5, 0, 5])
        ax_m.set_yticks([-5, 0, 5])
        ax_m.set_xlim(-7.5, 7.5)
        ax_m.set_ylim(-7.0, 7.0)
        ax_m.grid(True, lw=0.3)
        ax_m.set_xlabel("offset along the jaws, world x [mm] (+: backed out); marker shifted by roll")
        ax_m.set_ylabel("offset along the lobe's edge, world y [mm]")
        ax_m.set_title(f"{label}: approaches (label: rise)")

    handles = [plt.Line2D([], [], marker=markers[i % len(markers)], ls="", color="0.3",
                          label=f"grip {g:g} N m/rad") for i, g in enumerate(grips)]
    handles += [plt.Line2D([], [], marker="o", ls="", color="tab:red", label="a tet inverted"),
                plt.Line2D([], [], marker="o", ls="", color="tab:blue", fillstyle="none",
                           label="open: fails a condition")]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles))
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(a.out, dpi=100)


if __name__ == "__main__":
    main()
