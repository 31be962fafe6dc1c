#!/usr/bin/env python3
"""Worlds ticked per second by 1, 2, 3 ... daemons of a cluster on this machine
(docs/BENCHMARKS.md "Several daemons").

For each daemon count: starts that many physd of one cluster (memory only, loopback), creates
--worlds worlds without naming a daemon (the SDK's placement spreads them), loads --scene in
each, runs them all as fast as possible for --seconds, and reads their ticks: ticks per
second in all, per world, and the placement.

    tools/cluster_throughput.py [--daemons 1,2,3] [--worlds 6] [--scene box_stack] [--seconds 10]
"""
import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from move_bench import cluster  # noqa: E402


def run(n, args, domain):
    with cluster(n, domain) as c:
        worlds = [c.create_world(f"w{i}") for i in range(args.worlds)]
        for w in worlds:
            w.load_scene(args.scene)
        start = {s.world: s.tick for s in c.list_worlds()}
        t0 = time.monotonic()
        for w in worlds:
            w.run(0)
        time.sleep(args.seconds)
        for w in worlds:
            w.pause()
        elapsed = time.monotonic() - t0
        listed = c.list_worlds()
        ticks = sum(s.tick - start[s.world] for s in listed)
        per = {}
        for s in listed:
            per.setdefault(s.daemon, []).append(s.tick - start[s.world])
        placement = ", ".join(f"daemon {d}: {len(v)} worlds {sum(v) / elapsed:.0f} ticks/s"
                              for d, v in sorted(per.items()))
        print(f"{n} daemon(s), {args.worlds} x {args.scene}: {ticks / elapsed:.0f} world ticks/s "
              f"({ticks / elapsed / args.worlds:.1f} per world); {placement}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--daemons", default="1,2,3")
    ap.add_argument("--worlds", type=int, default=6)
    ap.add_argument("--scene", default="box_stack")
    ap.add_argument("--seconds", type=float, default=10)
    ap.add_argument("--domain", type=int, default=93)
    args = ap.parse_args()
    for n in [int(x) for x in args.daemons.split(",")]:
        run(n, args, args.domain)


if __name__ == "__main__":
    main()
