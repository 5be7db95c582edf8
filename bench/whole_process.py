#!/usr/bin/env python3
"""Whole-process wall time, side by side in one run: `taut calibrate REC` against
`python3 bench/scipy_compare.py REC --runs 1` on the same recording, interleaved so that both
see the same machine load. Each timing is the process from exec to exit: reading and parsing the
file, the calibration, the output (stdout to /dev/null).

    whole_process.py TAUT REC.csv [--runs N] [--scipy-runs M] [--old OLD_TAUT] [--parse-only READER]

With --parse-only, READER (`calib/examples/read_recording`: the same reader, the same threads)
runs interleaved too: the process that only reads and parses REC, the floor under the whole
calibration. Its row gives the whole process as a multiple of it.

With --old, an older build's `calibrate REC` runs interleaved with the new one's (old, new, old,
...) so that a speed change is measured side by side under the same load.
"""
import argparse
import os
import resource
import statistics
import subprocess
import sys
import time


def cpu_children():
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def timed(cmd):
    """(wall time, CPU time user + system of all its threads), s."""
    c0, t0 = cpu_children(), time.perf_counter()
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    dt, dc = time.perf_counter() - t0, cpu_children() - c0
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stderr.decode(errors='replace')}")
    return dt, dc


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("taut")
    ap.add_argument("recording")
    ap.add_argument("--runs", type=int, default=15, help="runs of taut calibrate")
    ap.add_argument("--scipy-runs", type=int, default=3, help="runs of the scipy script (each takes seconds)")
    ap.add_argument("--py", default=sys.executable)
    ap.add_argument("--label", default="taut calibrate REC", help="name of the taut row (e.g. an older build)")
    ap.add_argument("--no-compare", action="store_true", help="skip the --compare row (builds before the flag existed)")
    ap.add_argument("--old", help="an older taut build, run interleaved with TAUT and reported beside it")
    ap.add_argument("--parse-only", help="a program that only reads REC (calib/examples/read_recording), run interleaved")
    a = ap.parse_args()
    here = os.path.dirname(os.path.abspath(__file__))
    ours_cmd = [a.taut, "calibrate", a.recording]
    compare_cmd = ours_cmd + ["--compare"]
    scipy_cmd = [a.py, os.path.join(here, "scipy_compare.py"), a.recording, "--runs", "1"]
    timed(ours_cmd)  # page cache warm for both
    old_cmd = [a.old, "calibrate", a.recording] if a.old else None
    parse_cmd = [a.parse_only, a.recording] if a.parse_only else None
    ours, compare, scipy, old, parse = [], [], [], [], []
    per = max(1, a.runs // max(1, a.scipy_runs))
    while len(ours) < a.runs or len(scipy) < a.scipy_runs:
        for _ in range(per):
            if len(ours) < a.runs:
                if old_cmd:
                    old.append(timed(old_cmd))
                ours.append(timed(ours_cmd))
                if parse_cmd:
                    parse.append(timed(parse_cmd))
                if not a.no_compare:
                    compare.append(timed(compare_cmd))
        if len(scipy) < a.scipy_runs:
            scipy.append(timed(scipy_cmd))
    def row(label, runs, ref=None):
        wall = statistics.median(r[0] for r in runs)
        cpu = statistics.median(r[1] for r in runs)
        lo, hi = min(r[0] for r in runs), max(r[0] for r in runs)
        ratio = "" if ref is None else f"{ref[0] / wall:9.1f}x {ref[1] / cpu:9.1f}x"
        print(f"{label:50} {wall:9.3f} {lo:7.3f}-{hi:<7.3f} {cpu:9.3f} {ratio}")
        return wall, cpu

    print(f"whole process, {a.runs} / {a.scipy_runs} runs interleaved; medians; CPU = user + system of the process")
    print(f"{'':50} {'wall, s':>9} {'wall range, s':>15} {'CPU, s':>9} {'scipy/this':>10} {'(CPU)':>10}")
    ref = row("python3 bench/scipy_compare.py REC --runs 1", scipy)
    if old:
        row(f"old build: {a.old} calibrate REC", old, ref)
    whole = row(a.label, ours, ref)
    if compare:
        row(a.label + " --compare", compare, ref)
    if parse:
        p = row("parse only: " + os.path.basename(a.parse_only) + " REC", parse, ref)
        print(f"whole process / parse only: {whole[0] / p[0]:.2f}x by wall, {whole[1] / p[1]:.2f}x by CPU (goal <= 3x by wall)")

if __name__ == "__main__":
    sys.exit(main())
