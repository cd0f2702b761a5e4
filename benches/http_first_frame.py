#!/usr/bin/env python3
"""Issue 42's remote goal: the first complete frame of a 512^3 store over HTTP with 50 ms added
to every request, at `--lod auto`.

usage: http_first_frame.py VELLUM [N] [DELAY_MS]   (defaults 512 and 50)

Writes `phantom:shepp-logan:N` as a store (vellum convert), serves its folder from a threaded
HTTP server on 127.0.0.1 that sleeps DELAY_MS before every answer and counts the requests in
flight, and times `vellum render URL --lod auto` (no chunk cache, a 64 MiB GPU budget, so that
the store streams through the brick cache) against the same command on the folder. Prints the
wall times, the requests and the most in flight at once.
"""
import functools
import http.server
import json
import subprocess
import sys
import tempfile
import threading
import time


class State:
    lock = threading.Lock()
    in_flight = 0
    most = 0
    requests = 0


def handler_class(delay):
    class Slow(http.server.SimpleHTTPRequestHandler):
        # As a production server does: without it, the headers and the body leave in two
        # segments and the second waits ~40 ms for the client's delayed ACK (Nagle).
        disable_nagle_algorithm = True
        protocol_version = "HTTP/1.1"

        def handle_one_request(self):
            with State.lock:
                State.in_flight += 1
                State.most = max(State.most, State.in_flight)
            try:
                super().handle_one_request()
            finally:
                with State.lock:
                    State.in_flight -= 1

        def send_head(self):
            with State.lock:
                State.requests += 1
            time.sleep(delay)
            return super().send_head()

        def log_message(self, *args):
            pass

    return Slow


class Server(http.server.ThreadingHTTPServer):
    # socketserver listens with a backlog of 5. The renderer opens 16 connections at once, and
    # the kernel drops the SYNs past the backlog; the client sends them again a second later
    # (TCP's initial retransmission time-out), which stalled some runs for 0.8-1 s. A production
    # server listens with a backlog of hundreds (nginx 511).
    request_queue_size = 128


def render(vellum, source, out):
    start = time.perf_counter()
    done = subprocess.run([vellum, "render", source, "--lod", "auto", "--gpu-budget", "64",
                           "--cache-mib", "0", "--size", "512x512", "--camera", "30,20",
                           "--json", "--out", out], check=True, capture_output=True, text=True)
    wall = time.perf_counter() - start
    return wall, json.loads(done.stdout).get("bricks", {})


def main():
    vellum = sys.argv[1]
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 512
    delay = (int(sys.argv[3]) if len(sys.argv) > 3 else 50) / 1000
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([vellum, "convert", f"phantom:shepp-logan:{n}", f"{tmp}/s.ome.zarr"],
                       check=True, capture_output=True)
        server = Server(("127.0.0.1", 0), functools.partial(handler_class(delay), directory=tmp))
        threading.Thread(target=server.serve_forever, daemon=True).start()
        url = f"http://127.0.0.1:{server.server_address[1]}/s.ome.zarr"
        disk, _ = render(vellum, f"{tmp}/s.ome.zarr", f"{tmp}/disk.png")
        remote, bricks = render(vellum, url, f"{tmp}/http.png")
        server.shutdown()
        print(f"| store | source | first complete frame (wall, s) | requests | most in flight |")
        print("|---|---|---|---|---|")
        print(f"| {n}³ | folder | {disk:.2f} | — | — |")
        print(f"| {n}³ | HTTP, +{delay * 1000:.0f} ms a request | {remote:.2f} | {State.requests} | {State.most} |")
        print(f"\nbricks over HTTP: {json.dumps({k: bricks.get(k) for k in ['passes', 'bricks_loaded', 'chunks_decoded', 'complete']})}")


if __name__ == "__main__":
    main()
