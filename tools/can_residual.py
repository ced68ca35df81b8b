"""Residual probability that a random CAN frame passes the cobot protocol's checks, measured.

    python tools/can_residual.py [--frames N] [--seed S]

Four draws of N frames each, with a seeded generator:

* ``known id``: a uniformly random payload on each of the DBC's ids in turn, with the right id type,
  FD flag and length: only the CRC-32 (and then the DBC ranges) stands between it and the math.
  Theory: at most 2^-32 = 2.3e-10 per frame, so 0 expected at any N a run can reach. (A frame tied
  to a SYNC is checked by a receiver with no SYNC of its own: its counter is its count.)
* ``replayed``: a valid frame of a message tied to a SYNC (HOST_CMD, DEV_JOINTS, DEV_WRENCH: a
  random payload sealed with the CRC over a random full SYNC count), replayed k * 256 SYNCs later
  (k random up to 2^23, the receiver up to half a wrap off): its counter matches the receiver's
  again, only the full count in its CRC differs. Theory: 0 at any N, not a probability: the two
  counts differ in four consecutive bytes of the CRC's input, a burst CRC-32 always detects.
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
from teleop.master.cobot.database import Decoded, FrameDatabase, compute_crc32


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
    out["replayed"] = replays_passed(db, rng, n)
    out["seconds"] = time.perf_counter() - t0
    return out


def replays_passed(db: FrameDatabase, rng: np.random.Generator, n: int) -> int:
    """Of ``n`` valid frames tied to a SYNC replayed whole counter wraps later, how many pass the
    CRC (anything but ``stale`` or ``checksum``: decoded, or refused only later, by a range)."""
    tied = [(db.message(name).frame_id, db.message(name).length,
             db.by_name[name].get_signal_by_name(db.codecs[name].names[i]).start // 8)
            for name, i in db.counter.items()]
    passed = 0
    for j in range(n):
        fid, length, ctr = tied[j % len(tied)]
        k = int(rng.integers(1, 2**23 + 1))
        count = int(rng.integers(0, 2**32 - 256 * k - 128))
        body = bytearray(rng.bytes(length - 4))
        body[ctr] = count % 256
        data = bytes(body) + compute_crc32(fid, bytes(body), count).to_bytes(4, "little")
        out = db.decode(fid, data, sync_ref=count + 256 * k + int(rng.integers(-128, 128)))
        passed += getattr(out, "reason", None) not in ("stale", "checksum")
    return passed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000, help="frames per draw (default 10^6)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    n = args.frames
    r = measure(n, args.seed)
    theory = {"known id": 2.0**-32, "crc8 baseline": 1 / 256, "random frame": 7 / 2048 / 16 * 2.0**-32,
              "replayed": 0.0}
    print(f"{n} frames per draw, seed {args.seed}, {r['seconds']:.1f} s")
    print(f"{'draw':16s} {'passed':>8s} {'rate':>10s} {'95% bound':>10s} {'theory':>10s}")
    for k in ("known id", "random frame", "replayed", "crc8 baseline"):
        c = r[k]
        bound = 3.0 / n if c == 0 else (c + 2.0 * np.sqrt(c)) / n
        print(f"{k:16s} {c:8d} {c / n:10.3g} {bound:10.3g} {theory[k]:10.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
