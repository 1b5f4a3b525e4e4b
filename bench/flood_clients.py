"""A flood of clients against a robot server (``bench/robots.py --parts flood`` and the server's flood test): run
as a process of its own.

    python bench/flood_clients.py ADDRESS SECONDS SOCKETS [SERVER_KEY CLIENT_KEY_SECRET_FILE]

``SOCKETS`` DEALER sockets send ``health`` requests four at a time as fast as the server answers them (and
again after 50 ms without an answer, so dropped requests do not slow the flood); with keys, the sockets use the
admitted client key and, beside them, a new socket with an unknown random key connects every 5 ms (each one a
refused handshake). Runs at nice 10. Prints one line ``replies N sent M attempts K`` at the end.

From Python: ``launch(...)`` starts it, ``counts(its stdout)`` reads that line.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import zmq

from unilab_jax.robots import protocol
from unilab_jax.robots.keys import load_pair

RESEND_S = 0.05
BURST = 4


def flood(address: str, seconds: float, n: int, server_key: bytes = b"", key_file: str = "") -> tuple[int, int, int]:
    ctx = zmq.Context()
    pair = load_pair(key_file) if key_file else None

    def dealer(keys: tuple[bytes, bytes] | None) -> zmq.Socket:
        s = ctx.socket(zmq.DEALER)
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SNDHWM, 16)
        if keys is not None:
            s.curve_serverkey = server_key
            s.curve_publickey, s.curve_secretkey = keys
        s.connect(address)
        return s

    socks = [dealer(pair) for _ in range(n)]
    poller = zmq.Poller()
    for s in socks:
        poller.register(s, zmq.POLLIN)
    request = protocol.request("health", 1, "flood")
    last = dict.fromkeys(socks, 0.0)
    replies = sent = attempts = 0
    strangers: list[tuple[float, zmq.Socket]] = []
    end = time.monotonic() + seconds
    next_stranger = 0.0
    while (now := time.monotonic()) < end:
        for s, _ in poller.poll(1):
            while s.poll(0):
                s.recv()
                replies += 1
            last[s] = 0.0
        now = time.monotonic()
        for s in socks:
            if now - last[s] > RESEND_S:
                for _ in range(BURST):
                    try:
                        s.send(request, zmq.NOBLOCK)
                        sent += 1
                    except zmq.Again:
                        break
                last[s] = now
        if pair is not None and now > next_stranger:
            stranger = dealer(zmq.curve_keypair())
            stranger.send(request, zmq.NOBLOCK)
            strangers.append((now, stranger))
            attempts += 1
            next_stranger = now + 0.005
            while strangers and now - strangers[0][0] > 0.2:
                strangers.pop(0)[1].close(0)
    for s in socks + [s for _, s in strangers]:
        s.close(0)
    ctx.term()
    return replies, sent, attempts


def launch(address: str, seconds: float, sockets: int, server_key: str = "", key_file: str = "") -> subprocess.Popen:
    """This script as a process of its own (one BLAS thread, the checkout importable), its stdout piped."""
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    path = os.pathsep.join([repo, os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": path}
    keys = [server_key, key_file] if server_key else []
    return subprocess.Popen([sys.executable, os.path.abspath(__file__), address, str(seconds), str(sockets), *keys],
                            stdout=subprocess.PIPE, text=True, env=env)


def counts(output: str) -> dict[str, int]:
    """``replies N sent M attempts K`` (the process's last line) -> ``{"replies": N, "sent": M, "attempts": K}``."""
    words = output.split()
    return dict(zip(words[0::2], map(int, words[1::2]), strict=True))


if __name__ == "__main__":
    # The clients stand for other machines: on a 2-core machine they run at a lower priority than the server and
    # its owner, else the measurement is of the CPU they take rather than of the server.
    os.nice(10)
    address, seconds, n = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
    server_key, key_file = (sys.argv[4].encode(), sys.argv[5]) if len(sys.argv) > 5 else (b"", "")
    replies, sent, attempts = flood(address, seconds, n, server_key, key_file)
    print(f"replies {replies} sent {sent} attempts {attempts}", flush=True)
