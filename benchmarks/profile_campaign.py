"""Where a campaign's processor time goes, in every process of its tree.

Usage::

    python benchmarks/profile_campaign.py                  # the default campaign (warm caches)
    python benchmarks/profile_campaign.py --repeat 3       # three runs, the median of each cell
    python benchmarks/profile_campaign.py -- --preset ideal --no-plots   # gonio campaign options

Runs ``gonio campaign --quiet`` in a child process whose every process (the campaign's, its
forked calibration jobs, capture workers, plot process and the plot process's forks) is
sampled by a profiling timer (``ITIMER_PROF``: the process's processor time, user and
system, every 5 ms; the timer re-armed in each forked child). Each sample is put in one
category by the Python stack of the thread that was working (the main thread unless it
was waiting and another thread was not: the raw frames' write-behind thread); each
process's samples are scaled to its own measured user + system time (``getrusage``), and
the processor time of the programs a process ran and waited for (Radiance's ``rtrace`` for
the preview) is its own row. Nothing is asserted; the table is printed (the architecture
document's "Performance" section is this script's output). The campaign runs about 10-20 %
slower under the sampler; every process's share is what is measured, not its wall time.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

#: categories, in the order a stack is tested from its outermost frame inwards: the first
#: (outermost) frame that matches one of these decides, except that an import or numba's
#: loading of a compiled kernel anywhere in the stack decides first
CATEGORIES = (
    (
        "budget",
        ("/campaign/budget", "/campaign/cornell_budget", "campaign_budget", "budget_fields"),
    ),
    ("fit", ("/gonio/fit/",)),
    ("plots", ("/gonio/plots/", "/matplotlib/", "plot_worker.py:warm_matplotlib")),
    ("lens calibration", ("/calibration/lens.py", "calibrate.py:_lens_job")),
    ("calibration cache", ("/campaign/calcache.py",)),
    ("render", ("/simulator/",)),
    ("reduction", ("/calibration/", "knowledge.py:reduce_incidence", "knowledge.py:_")),
    ("raw frames and tables written", ("/gonio/io/", "/campaign/folder.py")),
)
LABELS = (
    "render", "reduction", "imports", "numba kernels loaded", "plots", "budget", "fit",
    "lens calibration", "calibration cache", "raw frames and tables written", "other",
)  # fmt: skip

#: the bootstrap run in the child: the sampler, then gonio's command line
_CHILD = r"""
import os, sys, signal, resource, threading, json, collections
OUT = sys.argv[1]
INTERVAL = 0.005
counts = collections.Counter()
IDLE = ("wait", "acquire", "get", "select", "poll", "_recv", "recv_bytes", "_worker",
        "sleep", "read", "join", "result")

def _key(frame):
    names = []
    while frame is not None:
        c = frame.f_code
        names.append(c.co_filename + ":" + c.co_name)
        frame = frame.f_back
    return tuple(reversed(names))  # outermost first

def _busy(frame):
    return frame is not None and frame.f_code.co_name not in IDLE

def _sample(signum, frame):
    main = threading.main_thread().ident
    stack = frame
    if not _busy(frame):
        for tid, f in sys._current_frames().items():
            if tid != main and _busy(f):
                stack = f
                break
    counts[_key(stack)] += 1

def _arm():
    counts.clear()
    signal.signal(signal.SIGPROF, _sample)
    signal.setitimer(signal.ITIMER_PROF, INTERVAL, INTERVAL)

def _flush():
    signal.setitimer(signal.ITIMER_PROF, 0, 0)
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    rec = {"pid": os.getpid(), "ppid": os.getppid(), "cpu": me.ru_utime + me.ru_stime,
           "children_cpu": kids.ru_utime + kids.ru_stime,
           "stacks": [[list(k), n] for k, n in counts.items()]}
    with open(os.path.join(OUT, f"{os.getpid()}.json"), "w") as f:
        json.dump(rec, f)

_exit = os._exit
def _exit_flushed(code):
    try:
        _flush()
    finally:
        _exit(code)
os._exit = _exit_flushed
os.register_at_fork(after_in_child=_arm)
import atexit
atexit.register(_flush)
_arm()
sys.argv = ["gonio"] + sys.argv[2:]
from gonio.cli import main
try:
    rc = main()
except SystemExit as e:
    rc = e.code
sys.exit(rc)
"""


def categorise(stack: list[str]) -> str:
    """The category of one sampled stack (outermost frame first)."""
    if any("numba/core/dispatcher.py" in s or "numba/core/caching.py" in s for s in stack):
        return "numba kernels loaded"
    if any("importlib._bootstrap" in s for s in stack):
        return "imports"
    for s in stack:
        for label, pats in CATEGORIES:
            if any(p in s for p in pats):
                return label
    return "other"


def _kind(rec: dict, recs: dict[int, dict], root: int) -> str:
    """The process's role, from its place in the tree and what it ran."""
    if rec["pid"] == root:
        return "campaign"
    stacks = [s for s, _ in rec["stacks"]]
    flat = " ".join(x for s in stacks for x in s)
    parent = recs.get(rec["ppid"])
    if "plot_worker.py:_serve" in flat and parent is not None and parent["pid"] == root:
        return "plot process"
    if parent is not None and parent["pid"] != root:
        return "plot forks"
    if "lbl.py:_incidence" in flat:
        return "capture workers"
    return "calibration jobs"


def profile_once(gonio_args: list[str]) -> dict:
    """One sampled campaign: ``{kind: {category: seconds}}`` and the process counts."""
    with tempfile.TemporaryDirectory() as d:
        out = Path(d, "samples")
        out.mkdir()
        args = ["campaign", "--quiet", "--out", str(Path(d, "campaign")), *gonio_args]
        subprocess.run([sys.executable, "-c", _CHILD, str(out), *args], check=True)
        recs = {r["pid"]: r for r in (json.loads(p.read_text()) for p in out.glob("*.json"))}
    root = next(pid for pid, r in recs.items() if r["ppid"] not in recs)
    table: dict[str, dict[str, float]] = {}
    procs: dict[str, int] = {}
    for rec in recs.values():
        kind = _kind(rec, recs, root)
        procs[kind] = procs.get(kind, 0) + 1
        n = sum(c for _, c in rec["stacks"])
        row = table.setdefault(kind, {})
        for stack, c in rec["stacks"]:
            label = categorise(stack)
            row[label] = row.get(label, 0.0) + rec["cpu"] * c / max(n, 1)
        if kind == "plot forks":  # Radiance's rtrace, run and waited for by the preview's fork
            row["Radiance (preview)"] = row.get("Radiance (preview)", 0.0) + rec["children_cpu"]
    return {"table": table, "processes": procs}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=1, help="runs (the median of each cell)")
    p.add_argument("--json", type=Path, help="also write the runs' tables here")
    p.add_argument("gonio_args", nargs="*", help="options of gonio campaign (after --)")
    args = p.parse_args(argv)
    if not 1 <= args.repeat <= 20:
        p.error(f"--repeat {args.repeat}: expected 1-20")
    runs = [profile_once(args.gonio_args) for _ in range(args.repeat)]
    kinds = ["campaign", "calibration jobs", "capture workers", "plot process", "plot forks"]
    kinds = [k for k in kinds if any(k in r["table"] for r in runs)]
    labels = [*LABELS, "Radiance (preview)"]

    def cell(kind: str, label: str) -> float:
        return statistics.median([r["table"].get(kind, {}).get(label, 0.0) for r in runs])

    procs = {k: max(r["processes"].get(k, 0) for r in runs) for k in kinds}
    head = ["what", *(f"{k} ({procs[k]})" for k in kinds), "total"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    totals = dict.fromkeys(kinds, 0.0)
    for label in labels:
        vals = [cell(k, label) for k in kinds]
        if sum(vals) < 0.005:
            continue
        for k, v in zip(kinds, vals):
            totals[k] += v
        shown = [f"{v:.2f}" if v >= 0.005 else "—" for v in vals]
        print(f"| {label} | " + " | ".join(shown) + f" | {sum(vals):.2f} |")
    print("| all | " + " | ".join(f"{totals[k]:.2f}" for k in kinds)
          + f" | {sum(totals.values()):.2f} |")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(runs, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
