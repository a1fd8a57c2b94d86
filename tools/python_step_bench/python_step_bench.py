#!/usr/bin/env python3
"""What stepping a scene from Python costs over stepping it from C++, measured in one run.

The scene runs to --start-step under its script and its state is kept. Then, --reps times and in
alternating order, the state is restored and --steps steps are taken twice: by a Python loop
(sim.follow_script(); sim.step()) and by the same loop in C++ (tactus.benchmark.cpp_steps). Both
do the same work bit for bit (checked: the states they end in are equal), so the difference is
the Python side's: the calls, the StepReport returned to Python, the GIL. Reported per step: the
median over the repetitions of wall time and of the thread's CPU time (which a loaded machine
does not inflate), and the Python/C++ ratio of the medians and the median of the paired ratios.

    export PYTHONPATH=$PWD/build/python
    /usr/bin/python3 tools/python_step_bench/python_step_bench.py [--scene scenes/liver_grasp.yaml]
"""
import argparse
import json
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]


def python_steps(sim, steps):
    wall0, cpu0 = time.perf_counter(), time.thread_time()
    for _ in range(steps):
        sim.follow_script()
        sim.step()
    return time.perf_counter() - wall0, time.thread_time() - cpu0


def main():
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="the module: export PYTHONPATH=$PWD/build/python (docs/api.md)\n\n"
               "Example:\n  python_step_bench.py --scene scenes/liver_grasp.yaml --steps 100 --reps 9")
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "liver_grasp.yaml"))
    parser.add_argument("--start-step", type=int, default=250,
                        help="steps under the script before the measured ones (liver_grasp: "
                             "in the grasp from about step 165)")
    parser.add_argument("--steps", type=int, default=100, help="steps per measurement")
    parser.add_argument("--reps", type=int, default=9, help="measurements of each")
    parser.add_argument("--json", help="write the figures to this new file")
    args = parser.parse_args()
    import tactus  # after the arguments: --help works without the module built

    sim = tactus.Simulation(tactus.Model.from_file(args.scene))
    for _ in range(args.start_step):
        sim.follow_script()
        sim.step()
    start = sim.state()
    runs = {"python": [], "cpp": []}
    for rep in range(args.reps):
        ends = {}
        order = ("python", "cpp") if rep % 2 == 0 else ("cpp", "python")
        for mode in order:
            sim.set_state(start)
            if mode == "python":
                wall, cpu = python_steps(sim, args.steps)
            else:
                wall, cpu = tactus.benchmark.cpp_steps(sim, args.steps)
            runs[mode].append((wall / args.steps, cpu / args.steps))
            ends[mode] = sim.state()
        if ends["python"] != ends["cpp"]:
            print("the Python and C++ loops ended in different states", file=sys.stderr)
            return 1

    def median(mode, k):
        return statistics.median(r[k] for r in runs[mode])

    out = {"scene": pathlib.Path(args.scene).name, "start_step": args.start_step,
           "steps": args.steps, "reps": args.reps}
    for k, name in ((0, "wall"), (1, "cpu")):
        py, cpp = median("python", k), median("cpp", k)
        paired = statistics.median(p[k] / c[k] for p, c in zip(runs["python"], runs["cpp"]))
        out[name] = {"python_ms": 1e3 * py, "cpp_ms": 1e3 * cpp, "ratio_of_medians": py / cpp,
                     "median_paired_ratio": paired}
        print(f"{name:>4} per step: Python {1e3 * py:.4f} ms, C++ {1e3 * cpp:.4f} ms; "
              f"Python / C++ {py / cpp:.4f} (median of paired ratios {paired:.4f})")
    print(f"{out['scene']}: {args.reps} x {args.steps} steps from step {args.start_step}, "
          f"each loop from the same state, same end state")
    if args.json:
        path = pathlib.Path(args.json)
        if path.exists():
            print(f"{path} exists: not replaced", file=sys.stderr)
            return 2
        path.write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
