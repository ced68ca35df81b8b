"""Link round trip on loopback between two processes at 1 kHz: Zenoh against raw UDP, same run.

The parent sends one wire-encoded ToolCommand frame each millisecond; an echo child process
sends every frame straight back (UDP: ``recvfrom``/``sendto``; Zenoh: a subscriber callback that
puts the bytes on the return key, the way :class:`teleop.link.zenoh_link.ZenohLink` is set up:
peer, scouting off, DROP, REAL_TIME, express). The parent decodes the echo (CRC and all) and
records now - send time for that sequence number. Prints p50/p90/p99/max in ms.

    python tools/link_bench.py [--n 5000] [--rate 1000]
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import threading
import time

import numpy as np

from teleop.link import ToolCommand, wire
from teleop.link.zenoh_link import make_config


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def echo_udp(port: int) -> None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    print("ready", flush=True)
    while True:
        data, addr = s.recvfrom(2048)
        if data == b"stop":
            return
        s.sendto(data, addr)


def echo_zenoh(endpoint: str) -> None:
    import zenoh

    session = zenoh.open(make_config(listen=endpoint))
    pub = session.declare_publisher("teleop/bench/fb", congestion_control=zenoh.CongestionControl.DROP,
                                    priority=zenoh.Priority.REAL_TIME, express=True)
    done = threading.Event()

    def on(sample):
        data = sample.payload.to_bytes()
        if data == b"stop":
            done.set()
        else:
            pub.put(data)

    sub = session.declare_subscriber("teleop/bench/cmd", on)
    print("ready", flush=True)
    done.wait()
    sub.undeclare()
    session.close()


def frame(k: int) -> bytes:
    return wire.encode(ToolCommand(seq=k, t_s=k * 1e-3, p_m=[0.1, 0.2, 0.3], R=np.eye(3),
                                   v_m_s=[0.0, 0.0, 0.01], w_rad_s=np.zeros(3)))


def pace(n: int, rate_hz: float, send, sent_s: np.ndarray) -> None:
    """Send frames 0..n-1 at ``rate_hz`` (sleep to ~0.2 ms before each slot, then spin)."""
    period = 1.0 / rate_hz
    t0 = time.perf_counter()
    for k in range(n):
        slot = t0 + k * period
        while (d := slot - time.perf_counter()) > 0:
            if d > 3e-4:
                time.sleep(d - 2e-4)
        data = frame(k)
        sent_s[k] = time.perf_counter()
        send(data)


def run_udp(n: int, rate_hz: float) -> np.ndarray:
    port = free_port()
    child = subprocess.Popen([sys.executable, __file__, "--echo", "udp", "--port", str(port)],
                             stdout=subprocess.PIPE, text=True)
    child.stdout.readline()
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.connect(("127.0.0.1", port))
    s.settimeout(0.5)
    sent, rtt = np.full(n, np.nan), np.full(n, np.nan)

    def rx():
        got = 0
        while got < n:
            try:
                data = s.recv(2048)
            except OSError:
                return
            now = time.perf_counter()
            k = wire.decode(data).seq
            rtt[k] = now - sent[k]
            got += 1

    th = threading.Thread(target=rx, daemon=True)
    th.start()
    pace(n, rate_hz, s.send, sent)
    th.join(1.0)
    s.send(b"stop")
    child.wait(5)
    s.close()
    return rtt


def run_zenoh(n: int, rate_hz: float) -> np.ndarray:
    import zenoh

    ep = f"tcp/127.0.0.1:{free_port()}"
    child = subprocess.Popen([sys.executable, __file__, "--echo", "zenoh", "--endpoint", ep],
                             stdout=subprocess.PIPE, text=True)
    child.stdout.readline()
    session = zenoh.open(make_config(connect=ep))
    sent, rtt = np.full(n, np.nan), np.full(n, np.nan)
    up = threading.Event()

    def on(sample):
        now = time.perf_counter()
        k = wire.decode(sample.payload.to_bytes()).seq
        if k >= 0 and not np.isnan(sent[k]):
            rtt[k] = now - sent[k]
        up.set()

    sub = session.declare_subscriber("teleop/bench/fb", on)
    pub = session.declare_publisher("teleop/bench/cmd", congestion_control=zenoh.CongestionControl.DROP,
                                    priority=zenoh.Priority.REAL_TIME, express=True)
    while not up.is_set():  # route up: probe frames until one comes back
        pub.put(frame(0))
        up.wait(0.05)
    time.sleep(0.1)
    pace(n, rate_hz, pub.put, sent)
    time.sleep(0.5)
    pub.put(b"stop")
    child.wait(5)
    sub.undeclare()
    session.close()
    return rtt


def row(name: str, rtt: np.ndarray, warmup: int) -> str:
    r = rtt[warmup:]
    ok = r[~np.isnan(r)] * 1e3
    if len(ok) == 0:
        return f"{name:<8} {len(r):>6} {0:>6}"
    p50, p90, p99 = np.percentile(ok, [50, 90, 99])
    return (f"{name:<8} {len(r):>6} {len(r) - len(ok):>6} {p50:>8.3f} {p90:>8.3f} {p99:>8.3f} "
            f"{ok.max():>8.3f}")


def figures(rtt: np.ndarray, warmup: int) -> dict:
    """p50/p90/p99/max round trip (ms) and frames lost, the first ``warmup`` left out."""
    r = rtt[warmup:]
    ok = r[~np.isnan(r)] * 1e3
    out = {"frames": len(r), "lost": int(len(r) - len(ok))}
    if len(ok):
        p50, p90, p99 = np.percentile(ok, [50, 90, 99])
        out.update(p50_ms=float(p50), p90_ms=float(p90), p99_ms=float(p99), max_ms=float(ok.max()))
    return out


def measure(n: int = 3000, rate_hz: float = 1000.0, warmup: int = 200) -> dict:
    """Both transports in one run, raw UDP first: {"udp": figures, "zenoh": figures}."""
    return {"udp": figures(run_udp(n, rate_hz), warmup), "zenoh": figures(run_zenoh(n, rate_hz), warmup)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5000, help="frames per transport")
    ap.add_argument("--rate", type=float, default=1000.0, help="send rate (Hz)")
    ap.add_argument("--warmup", type=int, default=200, help="frames left out of the figures")
    ap.add_argument("--echo", choices=("udp", "zenoh"), help=argparse.SUPPRESS)
    ap.add_argument("--port", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.echo == "udp":
        return echo_udp(a.port)
    if a.echo == "zenoh":
        return echo_zenoh(a.endpoint)
    print(f"round trip on loopback, two processes, {a.rate:.0f} Hz, {a.n} frames of "
          f"{wire.COMMAND_SIZE} B each (first {a.warmup} left out)")
    print(f"{'link':<8} {'frames':>6} {'lost':>6} {'p50 ms':>8} {'p90 ms':>8} {'p99 ms':>8} {'max ms':>8}")
    print(row("udp", run_udp(a.n, a.rate), a.warmup))
    print(row("zenoh", run_zenoh(a.n, a.rate), a.warmup))


if __name__ == "__main__":
    main()
