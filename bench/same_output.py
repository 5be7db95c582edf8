#!/usr/bin/env python3
"""Byte-for-byte output check between two `taut` builds: `taut calibrate` (stdout and `--json`, with
and without `--compare`) on a recording and on hostile copies of it, and `taut diagnose` (stdout and
`--json`) on a second recording. Used to show that a speed change does not change any result.

    same_output.py OLD_TAUT NEW_TAUT REC.csv [--diagnose REC2.csv] [--work DIR]

Hostile copies (each one change to the original): an absurd encoder value (1e308), an encoder spike,
an impossible tension, a tracker spike, a lost-count jump (every later encoder reading of a cable
shifted), fields with spaces, `nan`, an empty field, CR line ends; with --diagnose, the same nine
copies of REC2 as well. Exit status 1 if any output differs.
"""
import argparse
import os
import subprocess
import sys


def variants(lines):
    """(name, lines) for each hostile copy. lines[i] keeps its newline."""
    head = [i for i, l in enumerate(lines) if l.startswith("#") or l[:1].isalpha()]
    first = max(head) + 1
    n = len(lines) - first

    def edit(k, col, fn):
        out = list(lines)
        i = first + k
        f = out[i].rstrip("\r\n").split(",")
        f[col] = fn(f[col])
        out[i] = ",".join(f) + "\n"
        return out

    cols = lines[first - 1].rstrip("\r\n").split(",")
    l0, f0, px = cols.index("l0"), cols.index("f0"), cols.index("px")
    yield "absurd-encoder", edit(n // 3, l0, lambda v: "1e308")
    yield "encoder-spike", edit(n // 2, l0 + 1, lambda v: f"{float(v) + 0.35:.7f}")
    yield "impossible-tension", edit(n // 4, f0 + 2, lambda v: "-4000.0")
    yield "tracker-spike", edit(2 * n // 3, px, lambda v: f"{float(v) + 0.8:.6f}")
    jump = list(lines)
    for i in range(first + 3 * n // 5, len(lines)):
        f = jump[i].rstrip("\r\n").split(",")
        f[l0 + 3] = f"{float(f[l0 + 3]) + 0.0625:.7f}"
        jump[i] = ",".join(f) + "\n"
    yield "lost-count-jump", jump
    yield "spaces", edit(n // 5, l0 + 2, lambda v: f"  {v} ")
    yield "nan", edit(n // 6, f0 + 1, lambda v: "nan")
    yield "empty-field", edit(n // 7, f0 + 3, lambda v: "")
    yield "cr", [l.rstrip("\n") + "\r\n" for l in lines]


def run(cmd, json_path):
    """(exit status, stdout, stderr, the --json file or b"") of one command."""
    if os.path.exists(json_path):
        os.remove(json_path)
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    js = b""
    if os.path.exists(json_path):
        with open(json_path, "rb") as f:
            js = f.read()
    return r.returncode, r.stdout, r.stderr, js


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("recording")
    ap.add_argument("--diagnose", help="a recording to run `taut diagnose` on as well")
    ap.add_argument("--work", default=None, help="where to write the hostile copies (default: beside REC)")
    a = ap.parse_args()
    work = a.work or os.path.join(os.path.dirname(os.path.abspath(a.recording)), "hostile")
    os.makedirs(work, exist_ok=True)
    with open(a.recording, newline="") as f:
        lines = f.readlines()
    recs = [("original", a.recording)]
    for name, out in variants(lines):
        p = os.path.join(work, name + ".csv")
        with open(p, "w", newline="") as f:
            f.writelines(out)
        recs.append((name, p))
    cases = []
    js = os.path.join(work, "out.json")
    for name, p in recs:
        for flags in ([], ["--json", js], ["--compare"], ["--compare", "--json", js]):
            cases.append((f"calibrate {name} {' '.join(f for f in flags if f != js)}", ["calibrate", p] + flags))
    if a.diagnose:
        # The diagnosis on its recording and on the same nine hostile copies of it.
        with open(a.diagnose, newline="") as f:
            dlines = f.readlines()
        drecs = [("original", a.diagnose)]
        for name, out in variants(dlines):
            p = os.path.join(work, "diagnose-" + name + ".csv")
            with open(p, "w", newline="") as f:
                f.writelines(out)
            drecs.append((name, p))
        for name, p in drecs:
            for flags in ([], ["--json", js]):
                cases.append((f"diagnose {name} {' '.join(f for f in flags if f != js)}", ["diagnose", p] + flags))
    bad = 0
    for label, args in cases:
        o, n = run([a.old] + args, js), run([a.new] + args, js)
        same = o == n
        bad += not same
        print(f"{'same' if same else 'DIFFERENT':9} exit {o[0]}/{n[0]} {len(o[1]):6} B stdout {len(o[3]):6} B json  {label}")
        if not same:
            for what, x, y in (("stdout", o[1], n[1]), ("stderr", o[2], n[2]), ("json", o[3], n[3])):
                if x != y:
                    xl, yl = x.decode(errors="replace").splitlines(), y.decode(errors="replace").splitlines()
                    for i, (u, v) in enumerate(zip(xl, yl)):
                        if u != v:
                            print(f"    {what} line {i + 1}:\n      old: {u}\n      new: {v}")
                            break
    print(f"{len(cases) - bad} of {len(cases)} outputs identical")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
