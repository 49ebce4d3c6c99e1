#!/usr/bin/env python3
"""Break bite -> PLC latency into its stages from a gateway's stage-timing file
(MILLGATE_STAGE_TIMINGS, the temporary instrumentation of issue 42 item 1).

usage: stages.py FILE [--skip-s 15]
"""
import bisect
import sys
from collections import defaultdict


def pct(values, q):
    if not values:
        return float("nan")
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def main():
    path = sys.argv[1]
    skip_ns = float(sys.argv[sys.argv.index("--skip-s") + 1]) * 1e9 if "--skip-s" in sys.argv else 15e9
    rounds, jobs, bites, publishes, plcs, commits = [], defaultdict(list), [], [], [], []
    for line in open(path):
        kind, *f = line.split()
        f = [int(x) for x in f]
        if kind == "round":
            rounds.append(f)
        elif kind == "job":
            jobs[f[0]].append(f[1:])
        elif kind == "bite":
            bites.append(f)
        elif kind == "publish":
            publishes.append((f[0], f[1], set(zip(f[2::2], f[3::2]))))
        elif kind == "plc":
            plcs.append((f[:7], set(f[7:])))
        elif kind == "commit":
            commits.append(f)
    rounds.sort()
    round_starts = [r[0] for r in rounds]
    for d in jobs:
        jobs[d].sort()
    publishes.sort()
    publish_starts = [p[0] for p in publishes]
    plcs.sort(key=lambda p: p[0][2])
    plc_taken = [p[0][2] for p in plcs]
    stages = defaultdict(list)
    t0 = min(r[0] for r in rounds)
    for d, handed, a0, a1 in bites:
        if a0 - t0 < skip_ns:
            continue
        r = rounds[bisect.bisect_right(round_starts, a0) - 1]
        js = jobs[d]
        j = js[bisect.bisect_right([x[0] for x in js], a0) - 1]
        i = bisect.bisect_left(publish_starts, a1)
        while i < len(publishes) and (d, handed) not in publishes[i][2]:
            i += 1
        if i == len(publishes):
            continue
        p0, p1, _ = publishes[i]
        k = bisect.bisect_left(plc_taken, p1)
        while k < len(plcs) and handed not in plcs[k][1]:
            k += 1
        if k == len(plcs):
            continue
        period, woke, taken, encoded, settled, ack, requests = plcs[k][0]
        stages["block wait (handed -> round start)"].append(r[0] - handed)
        stages["pool wait (round start -> job start)"].append(j[0] - r[0])
        stages["job before the bite"].append(a0 - j[0])
        stages["bite analysis"].append(a1 - a0)
        stages["job after the bite"].append(j[1] - a1)
        stages["publication wait (job end -> publish)"].append(p0 - j[1])
        stages["publish (board change)"].append(p1 - p0)
        stages["hop to the PLC writer (publish -> results taken)"].append(taken - p1)
        stages["encode"].append(encoded - taken)
        stages["history wait (commit)"].append(settled - encoded)
        stages["FC 16 write and ack"].append(ack - settled)
        stages["total (handed -> ack)"].append(ack - handed)
        stages["bites in the round"].append(r[3] and sum(1 for b in bites if r[0] <= b[2] <= r[1]))
    n = len(stages["total (handed -> ack)"])
    print(f"{n} bites after the first {skip_ns / 1e9:.0f} s")
    print(f"{'stage':52} {'mean':>8} {'p50':>8} {'p90':>8} {'p99':>8} {'max':>8}  (ms)")
    for name, values in stages.items():
        scale = 1 if name.startswith("bites") else 1e-6
        v = [x * scale for x in values]
        print(f"{name:52} {sum(v) / len(v):8.3f} {pct(v, .5):8.3f} {pct(v, .9):8.3f} {pct(v, .99):8.3f} {max(v):8.3f}")
    late = [r for r in rounds if r[0] - t0 >= skip_ns]
    span_s = (late[-1][1] - late[0][0]) / 1e9 if late else 1
    busy = sum(r[1] - r[0] for r in late) / 1e9
    print(f"rounds: {len(late)} in {span_s:.1f} s ({len(late) / span_s:.0f}/s), busy {100 * busy / span_s:.1f}% of the time;"
          f" messages per round p50 {pct([r[2] for r in late], .5)}, jobs per round p50 {pct([r[3] for r in late], .5)} max {max(r[3] for r in late)}")
    job_ns = [j[1] - j[0] for d in jobs for j in jobs[d] if j[0] - t0 >= skip_ns and j[2] == 0]
    print(f"jobs without a bite: {len(job_ns)}, mean {sum(job_ns) / max(1, len(job_ns)) / 1e3:.1f} us, p99 {pct(job_ns, .99) / 1e3:.1f} us")
    late_commits = [c for c in commits if c[0] - t0 >= skip_ns]
    if late_commits:
        ms = [(c[1] - c[0]) / 1e6 for c in late_commits]
        print(f"history commits: {len(ms)}, mean {sum(ms) / len(ms):.3f} ms, p99 {pct(ms, .99):.3f} ms, max {max(ms):.3f} ms, events p50 {pct([c[2] for c in late_commits], .5)}")
    late_plc = [p[0] for p in plcs if p[0][2] - t0 >= skip_ns]
    if late_plc:
        w = [(p[5] - p[4]) / 1e6 for p in late_plc]
        print(f"PLC writes: {len(late_plc)}, write+ack mean {sum(w) / len(w):.3f} ms p99 {pct(w, .99):.3f}, requests p50 {pct([p[6] for p in late_plc], .5)}")
    # Bites per burst: bites whose blocks were handed within 50 ms of the first of a burst.
    hs = sorted(b[1] for b in bites if b[2] - t0 >= skip_ns)
    bursts, i = [], 0
    while i < len(hs):
        j = i
        while j < len(hs) and hs[j] - hs[i] < 50e6:
            j += 1
        bursts.append(j - i)
        i = j
    if bursts:
        print(f"bursts (bites handed within 50 ms): {len(bursts)}, size mean {sum(bursts) / len(bursts):.1f}, max {max(bursts)}")


main()
