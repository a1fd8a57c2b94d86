#!/usr/bin/python3
"""Plot a tactus-jitter CSV: period-error histogram (log scale) and a time series.

Usage: jitter_plot.py RECORDS.csv OUT.png [--title T] [--baseline BARE.csv]

RECORDS.csv is what `tactus-jitter --csv` writes (one row per haptic tick); BARE.csv
("tick,late_ns") is the bare-loop baseline the tool writes when --baseline is on. Run it with
/usr/bin/python3 (Debian's python3-matplotlib); no other dependency.
"""
import argparse
import csv
import sys


def read_columns(path, names):
    cols = {n: [] for n in names}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            for n in names:
                cols[n].append(float(row[n]))
    return cols


def main():
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Example:\n  jitter_plot.py jitter.csv jitter.png --baseline jitter_baseline.csv")
    ap.add_argument("records")
    ap.add_argument("out")
    ap.add_argument("--title", default="haptic tick timing")
    ap.add_argument("--baseline", default=None, help="bare-loop CSV (tick,late_ns)")
    a = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = read_columns(a.records, ["woken_ns", "period_error_ns", "tick_ns", "solve_ns"])
    if not c["woken_ns"]:
        sys.exit(f"{a.records}: no records")
    t0 = c["woken_ns"][0]
    t_s = [(w - t0) * 1e-9 for w in c["woken_ns"]]
    err_us = [x * 1e-3 for x in c["period_error_ns"]]
    tick_us = [x * 1e-3 for x in c["tick_ns"]]
    solve_us = [x * 1e-3 for x in c["solve_ns"]]
    bare_us = None
    if a.baseline:
        bare_us = [x * 1e-3 for x in read_columns(a.baseline, ["late_ns"])["late_ns"]]

    fig, (ax_h, ax_t) = plt.subplots(2, 1, figsize=(10, 8))
    hi = max(err_us + (bare_us or [])) or 1.0
    lo = min(err_us + (bare_us or []))
    bins = 200
    ax_h.hist(err_us, bins=bins, range=(min(lo, 0.0), hi), log=True, alpha=0.7,
              label=f"haptic loop ({len(err_us)} ticks)")
    if bare_us:
        ax_h.hist(bare_us, bins=bins, range=(min(lo, 0.0), hi), log=True, alpha=0.5,
                  label=f"bare loop ({len(bare_us)} ticks)")
    ax_h.set_xlabel("period error: woken - scheduled [us]")
    ax_h.set_ylabel("ticks (log scale)")
    ax_h.legend()
    ax_h.set_title(a.title)

    ax_t.plot(t_s, tick_us, ".", markersize=1.5, label="tick duration", alpha=0.6)
    ax_t.plot(t_s, solve_us, ".", markersize=1.5, label="solve time", alpha=0.6)
    ax_t.plot(t_s, err_us, ".", markersize=1.5, label="period error", alpha=0.8)
    ax_t.set_yscale("symlog", linthresh=1.0)
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel("[us] (symlog)")
    ax_t.legend(markerscale=8)
    fig.tight_layout()
    fig.savefig(a.out, dpi=110)


if __name__ == "__main__":
    main()
