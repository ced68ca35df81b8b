"""Residual probability that a random CAN frame passes the cobot protocol's checks, measured.

    python tools/can_residual.py [--frames N] [--seed S]

Three draws of N frames each, with a seeded generator:

* ``known id``: a uniformly random payload on each of the DBC's ids in turn, with the right id type,
  FD flag and length: only the CRC-32 (and then the DBC ranges) stands between it and the math.
  Theory: at most 2^-32 = 2.3e-10 per frame, so 0 expected at any N a run can reach.
* ``random frame``: a random 11-bit id, a random CAN FD length, a random payload (what a babbling
  node or a broken gateway sends): the id, the length and the CRC must all match.
* ``crc8 baseline``: the known-id payloads checked with crccheck's CRC-8 SAE J1850 over all but the
  last byte (the protocol's former check): theory 1/256, the measured rate shows the draw can see
  a weak check.

Prints each count, the rate, and the one-sided 95 % upper bound on the rate (3/N when none pass).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from crccheck.crc import Crc8SaeJ1850

from teleop.can.busmodel import FD_LENGTHS
from teleop.master.cobot.database import Decoded, FrameDatabase


def measure(n: int, seed: int) -> dict:
    db = FrameDatabase()
    rng = np.random.default_rng(seed)
    ids = [m.frame_id for m in db.db.messages]
    length = {m.frame_id: m.length for m in db.db.messages}
    out = {}
    t0 = time.perf_counter()
    passed = weak = 0
    for k in range(n):
        fid = ids[k % len(ids)]
        data = rng.bytes(length[fid])
        passed += isinstance(db.decode(fid, data), Decoded)
        weak += Crc8SaeJ1850.calc(data[:-1]) == data[-1]
    out["known id"] = passed
    out["crc8 baseline"] = weak
    fids = rng.integers(0, 0x800, n)
    lens = rng.choice(np.array(FD_LENGTHS), n)
    out["random frame"] = sum(isinstance(db.decode(int(f), rng.bytes(int(m))), Decoded) for f, m in zip(fids, lens))
    out["seconds"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000, help="frames per draw (default 10^6)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    n = args.frames
    r = measure(n, args.seed)
    theory = {"known id": 2.0**-32, "crc8 baseline": 1 / 256, "random frame": 7 / 2048 / 16 * 2.0**-32}
    print(f"{n} frames per draw, seed {args.seed}, {r['seconds']:.1f} s")
    print(f"{'draw':16s} {'passed':>8s} {'rate':>10s} {'95% bound':>10s} {'theory':>10s}")
    for k in ("known id", "random frame", "crc8 baseline"):
        c = r[k]
        bound = 3.0 / n if c == 0 else (c + 2.0 * np.sqrt(c)) / n
        print(f"{k:16s} {c:8d} {c / n:10.3g} {bound:10.3g} {theory[k]:10.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
