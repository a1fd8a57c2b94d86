#!/usr/bin/python3
"""The accuracy report's section on the compliance models compared on the same states
(w_states.csv of tactus-accuracy): tables, the cause of the warped model's outliers and the
before/after plot of its bound. Used by scripts/accuracy_report.py.
"""
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def num(row, key):
    return float(row[key])


def pct(x):
    return f"{100.0 * x:.3g}"


STATE_MODELS = ["exact", "warped", "warped_bounded", "rest", "uncoupled"]


def quantile(v, p):
    v = sorted(v)
    return v[min(len(v) - 1, int(p * len(v)))] if v else 0.0


def median(v):
    return quantile(v, 0.5)


def ranks(v):
    order = sorted(range(len(v)), key=lambda i: v[i])
    r = [0.0] * len(v)
    for k, i in enumerate(order):
        r[i] = float(k)
    return r


def spearman(a, b):
    ra, rb = ranks(a), ranks(b)
    n = len(a)
    if n < 3:
        return float("nan")
    ma, mb = sum(ra) / n, sum(rb) / n
    cov = sum((x - ma) * (y - mb) for x, y in zip(ra, rb))
    va = math.sqrt(sum((x - ma) ** 2 for x in ra))
    vb = math.sqrt(sum((y - mb) ** 2 for y in rb))
    return cov / (va * vb) if va > 0 and vb > 0 else float("nan")


def states_table(rows):
    out = [
        "| model | states | W error median / p90 / max [%] | probe W error median / max [%] "
        "(states > 20 %) | force error median / p90 / max [%] | force error / sum f_n max [%] "
        "| exact fallbacks | step [ms] | W build [ms] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for m in STATE_MODELS:
        sel = [r for r in rows if r["model"] == m]
        if not sel:
            continue
        w = [num(r, "w_rel_err") for r in sel]
        pw = [num(r, "probe_w_rel_err") for r in sel]
        fe = [num(r, "force_rel_err") for r in sel]
        fn = [num(r, "force_rel_err") * num(r, "force_exact_n") / num(r, "normal_force_sum_n")
              for r in sel if num(r, "normal_force_sum_n") > 0]
        out.append(
            f"| {m} | {len(sel)} | {pct(median(w))} / {pct(quantile(w, 0.9))} / {pct(max(w))} "
            f"| {pct(median(pw))} / {pct(max(pw))} ({sum(x > 0.2 for x in pw)}) "
            f"| {pct(median(fe))} / {pct(quantile(fe, 0.9))} / {pct(max(fe))} "
            f"| {pct(max(fn) if fn else 0)} | {sum(int(r['exact_fallback']) for r in sel)} "
            f"| {median([num(r, 'step_ms') for r in sel]):.2f} "
            f"| {median([num(r, 'update_compliance_build_w_ms') for r in sel]):.3f} |")
    return "\n".join(out)


def cause_table(rows):
    """The warped model's probe W error by how crushed the elements near the jaws are."""
    sel = [r for r in rows if r["model"] == "warped"]
    bins = [(0.9, 10.0, "> 0.9"), (0.6, 0.9, "0.6 - 0.9"), (0.4, 0.6, "0.4 - 0.6"),
            (-10.0, 0.4, "< 0.4")]
    out = ["| min det F near the jaws | states | min rotation coherence near the jaws (median) "
           "| warped probe W error median / max [%] | warped force error median [%] |",
           "|---|---|---|---|---|"]
    for lo, hi, lab in bins:
        b = [r for r in sel if lo <= num(r, "min_det_near") < hi]
        if not b:
            continue
        pw = [num(r, "probe_w_rel_err") for r in b]
        out.append(f"| {lab} | {len(b)} "
                   f"| {median([num(r, 'min_rotation_coherence_near') for r in b]):.4f} "
                   f"| {pct(median(pw))} / {pct(max(pw))} "
                   f"| {pct(median([num(r, 'force_rel_err') for r in b]))} |")
    pw = [num(r, "probe_w_rel_err") for r in sel]
    rho_c = spearman(pw, [-num(r, "min_rotation_coherence_near") for r in sel])
    rho_d = spearman(pw, [-num(r, "min_det_near") for r in sel])
    inv = sum(int(r["inverted_near"]) > 0 for r in sel)
    out.append("")
    out.append(f"Spearman rank correlation of the warped probe W error with the rotation spread "
               f"(1 - coherence) near the jaws: {rho_c:.2f}; with the compression (1 - det F): "
               f"{rho_d:.2f}. States with an inverted element near the jaws: {inv} of {len(sel)}.")
    return "\n".join(out)


def plot_states(rows, meta, path):
    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(18, 4.8))
    colors = {"warped": "tab:blue", "warped_bounded": "tab:green", "rest": "tab:orange",
              "uncoupled": "tab:red"}
    for m in ["warped", "warped_bounded", "rest", "uncoupled"]:
        sel = [r for r in rows if r["model"] == m]
        ax1.plot([num(r, "t_s") for r in sel], [100 * num(r, "probe_w_rel_err") for r in sel],
                 lw=1, color=colors[m], label=m)
    warped = [r for r in rows if r["model"] == "warped"]
    axd = ax1.twinx()
    axd.plot([num(r, "t_s") for r in warped], [num(r, "min_det_near") for r in warped], lw=0.8,
             color="gray", ls=":", label="min det F near the jaws")
    axd.set_ylabel("min det F near the jaws (dotted)")
    ax1.set_xlabel("t [s] (the exact reference's script)")
    ax1.set_ylabel("W error on the probe rows [%]")
    ax1.set_title("(a) W error per state along one exact trajectory", fontsize=10)
    ax1.grid(True, alpha=0.3)
    ax1.legend(fontsize=7, loc="upper left")
    xs = [max(1e-6, 1 - num(r, "min_rotation_coherence_near")) for r in warped]
    ax2.scatter(xs, [num(r, "probe_w_rel_err") for r in warped], s=8,
                c=[num(r, "min_det_near") for r in warped], cmap="viridis")
    ax2.set_xscale("log")
    ax2.set_yscale("log")
    ax2.set_xlabel("1 - min rotation coherence near the jaws (colour: min det F)")
    ax2.set_ylabel("warped W error on the probe rows")
    ax2.set_title("(b) the cause: element rotations spread where the jaws crush", fontsize=10)
    ax2.grid(True, which="both", alpha=0.3)
    for m, ls in [("warped", "-"), ("warped_bounded", "--")]:
        for key, c in [("probe_w_rel_err", "tab:blue"), ("w_rel_err", "tab:purple")]:
            v = sorted(100 * num(r, key) for r in rows if r["model"] == m)
            if v:
                ax3.plot(v, [(i + 1) / len(v) for i in range(len(v))], color=c, ls=ls,
                         label=f"{m}, {'probe' if key.startswith('probe') else 'problem'} W")
    ax3.axvline(20, color="k", lw=0.6, ls=":")
    ax3.set_xlabel("W error [%]")
    ax3.set_ylabel("fraction of states")
    ax3.set_title(f"(c) before / after the bound (exact_below_coherence "
                  f"{meta.get('coherence_bound', '')})", fontsize=10)
    ax3.grid(True, alpha=0.3)
    ax3.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def states_section(rows, meta):
    if not rows:
        return ""
    return f"""### Compliance models on the same states

One exact reference trajectory ({rows[0]['mesh']}, the scene's script, exact W, CHOLMOD, NSGS
{float(meta['reference_tolerance']):.0e}, the scene's contact passes). At each sampled state in
contact its pre-step state is restored into one simulation per model, which steps once with the
same device target and a single contact pass: the same contacts, rows and `delta_free`, only W
differs. W error: `||W - W_exact||_F / ||W_exact||_F` of the whole problem (tool compliance
included) and on the probe rows (x, y, z at the 24 surface nodes nearest the tool, tissue only,
the measure of the W table above); force error: `|F - F_exact| / |F_exact|` of the contact force
on the tool (a pinch's net force is a small difference of large jaw forces, so also against the
sum of the normal forces). **warped_bounded** is warped with `compliance.exact_below_coherence:
{meta.get('coherence_bound', '')}`. Times: the probe steps (direct CHOLMOD; median).

{states_table(rows)}

Where the warped model's error comes from (warped probe W error by the smallest det F of the
elements at the 24 nodes nearest the tool):

{cause_table(rows)}

![compliance on the same states](accuracy_w_states.png)
"""
