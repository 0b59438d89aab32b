"""Time and memory of generating the default simulated benchmark.

For each hysteresis mechanism, in a fresh Python process (so that the peak
resident memory belongs to that mechanism alone), this script

1. times ``make_benchmark(cache=False, mechanism=m)`` (best of ``--repeat``
   calls; 4 catheters x 17 settings x 3 runs = 204 runs by default), and
   splits that time into the hysteresis time loop (the simulator's function
   ``simulate_transmission``, the only per-sample Python loop) and the rest,
   by the loop's share of one more generation under :mod:`cProfile`;
2. records the process's peak resident set size (``ru_maxrss``) after the
   timed calls, then runs one more generation under :mod:`tracemalloc` for
   the peak of Python-level allocations (numpy arrays included);
3. generates once more with ``cache=True`` into a temporary data folder, and
   times the second ``cache=True`` call, which loads the file instead.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_simulator.py
    .venv/bin/python benchmarks/bench_simulator.py --mechanism play --repeat 3

The table is printed in Markdown. The target is a generation time of at most
``--target`` seconds (30 s by default) on a 2-core machine.
"""

import argparse
import cProfile
import gc
import json
import os
import pstats
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc

from _machine import machine_lines

MECHANISMS = ("play", "bouc_wen", "dahl_creep")
MB = 1024.0**2
#: The simulator's per-sample time loop, found by name in the profile.
LOOP_FUNCTION = "simulate_transmission"


def _max_rss_mb():
    """Peak resident set size of this process (MB; ru_maxrss is KiB on Linux)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024.0 if sys.platform != "darwin" else rss / MB


def _loop_share(make_benchmark, kwargs):
    """Share of one generation's time spent in the hysteresis time loop, under cProfile.

    Only Python-level calls are profiled (``builtins=False``). The profiler's
    cost per call weighs more on the loop's many small steps than on the
    vectorised rest, so the share somewhat overstates the loop's share of an
    unprofiled generation.
    """
    profiler = cProfile.Profile(builtins=False)
    profiler.runcall(make_benchmark, cache=False, **kwargs)
    profile = pstats.Stats(profiler).get_stats_profile()
    if LOOP_FUNCTION not in profile.func_profiles:
        raise RuntimeError(f"no function {LOOP_FUNCTION!r} in the profile; update this script")
    return float(profile.func_profiles[LOOP_FUNCTION].cumtime) / profile.total_tt


def _child(args):
    """Measure one mechanism in this (fresh) process; print one JSON line."""
    import numpy as np  # noqa: F401  (imported before the baseline RSS)

    from skcath.datasets import make_benchmark

    rss_start = _max_rss_mb()
    kwargs = {"n_catheters": args.n_catheters, "n_runs": args.n_runs, "mechanism": args.mechanism}
    totals = []
    for _ in range(args.repeat):
        start = time.perf_counter()
        bunch = make_benchmark(cache=False, **kwargs)
        totals.append(time.perf_counter() - start)
        n_samples = len(bunch.X)
        n_runs = len(bunch.runs)
        del bunch
        gc.collect()
    best = int(np.argmin(totals))
    rss_peak = _max_rss_mb()
    loop_share = _loop_share(make_benchmark, kwargs)

    tracemalloc_peak = float("nan")
    if not args.no_tracemalloc:
        tracemalloc.start()
        bunch = make_benchmark(cache=False, **kwargs)
        tracemalloc_peak = tracemalloc.get_traced_memory()[1] / MB
        tracemalloc.stop()
        del bunch
        gc.collect()

    save_s = load_s = file_mb = float("nan")
    if not args.no_cache:
        with tempfile.TemporaryDirectory() as data_home:
            start = time.perf_counter()
            make_benchmark(cache=True, data_home=data_home, **kwargs)
            save_s = time.perf_counter() - start
            start = time.perf_counter()
            make_benchmark(cache=True, data_home=data_home, **kwargs)
            load_s = time.perf_counter() - start
            file_mb = sum(e.stat().st_size for e in os.scandir(data_home)) / MB

    print(
        json.dumps(
            {
                "mechanism": args.mechanism,
                "runs": n_runs,
                "samples": n_samples,
                "seconds": totals[best],
                "seconds_all": totals,
                "loop_seconds": loop_share * totals[best],
                "loop_share": loop_share,
                "rss_start_mb": rss_start,
                "rss_peak_mb": rss_peak,
                "tracemalloc_peak_mb": tracemalloc_peak,
                "generate_and_save_seconds": save_s,
                "load_seconds": load_s,
                "cache_file_mb": file_mb,
            }
        )
    )


def _machine():
    return machine_lines()


def _table(results, target):
    head = (
        "| mechanism | runs | samples | seconds | samples/s | hysteresis loop s | rest s "
        "| tracemalloc peak MB | max RSS MB | seconds / target | cached load s | load / generation |"
    )
    rule = "|" + "|".join(["---"] + ["---:"] * 11) + "|"
    rows = [head, rule]
    for r in results:
        rows.append(
            f"| {r['mechanism']} | {r['runs']} | {r['samples']:,} | {r['seconds']:.1f} "
            f"| {r['samples'] / r['seconds']:,.0f} | {r['loop_seconds']:.1f} "
            f"| {r['seconds'] - r['loop_seconds']:.1f} | {r['tracemalloc_peak_mb']:.0f} "
            f"| {r['rss_peak_mb']:.0f} | {r['seconds'] / target:.2f} | {r['load_seconds']:.2f} "
            f"| {r['load_seconds'] / r['seconds']:.3f} |"
        )
    return "\n".join(rows)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mechanism", choices=(*MECHANISMS, "all"), default="all",
                        help="hysteresis mechanism to measure (default: all three)")
    parser.add_argument("--repeat", type=int, default=1,
                        help="timed generations per mechanism; the best is reported (default: 1)")
    parser.add_argument("--n-catheters", type=int, default=4, help="catheters (default: 4)")
    parser.add_argument("--n-runs", type=int, default=3, help="runs per shaft setting (default: 3)")
    parser.add_argument("--target", type=float, default=30.0,
                        help="target generation time in seconds (default: 30)")
    parser.add_argument("--no-tracemalloc", action="store_true", help="skip the tracemalloc generation")
    parser.add_argument("--no-cache", action="store_true", help="skip the cached-load measurement")
    parser.add_argument("--json", metavar="PATH", help="also write the raw results to this JSON file")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")

    if args.child:
        _child(args)
        return 0

    mechanisms = MECHANISMS if args.mechanism == "all" else (args.mechanism,)
    results = []
    for mechanism in mechanisms:
        cmd = [sys.executable, os.path.abspath(__file__), "--child", "--mechanism", mechanism,
               "--repeat", str(args.repeat), "--n-catheters", str(args.n_catheters),
               "--n-runs", str(args.n_runs)]
        cmd += ["--no-tracemalloc"] * args.no_tracemalloc + ["--no-cache"] * args.no_cache
        print(f"measuring {mechanism} ...", file=sys.stderr, flush=True)
        done = subprocess.run(cmd, check=True, capture_output=True, text=True)
        results.append(json.loads(done.stdout.strip().splitlines()[-1]))

    print("\n".join(_machine()))
    print(f"benchmark: {args.n_catheters} catheters x 17 settings x {args.n_runs} runs; "
          f"best of {args.repeat}; target {args.target:g} s\n")
    print(_table(results, args.target))
    print()
    for r in results:
        print(
            f"{r['mechanism']}: all timed runs {', '.join(f'{s:.1f}' for s in r['seconds_all'])} s; "
            f"hysteresis loop {100 * r['loop_seconds'] / r['seconds']:.0f} % of generation; "
            f"RSS {r['rss_start_mb']:.0f} MB after imports; generate + save {r['generate_and_save_seconds']:.1f} s, "
            f"cache file {r['cache_file_mb']:.0f} MB"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": _machine(), "args": vars(args), "results": results}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
