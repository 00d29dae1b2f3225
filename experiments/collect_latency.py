"""Step rate and press-to-frame latency of ``cogail collect``, with two clients in Python (no browser).

    python experiments/collect_latency.py --task fetchq --steps 300
    python experiments/collect_latency.py --task handover --steps 200 --hz 15

It serves a table in this process (or talks to a running one: ``--url http://HOST:PORT`` with ``--code-human`` /
``--code-robot`` for a table open to the network), seats two clients that speak the page's protocol (join, input,
long-polled views), and has each "press a key" every few frames: a new command with a new ``seq``. The latency of a
press is the time from sending it to receiving the first frame whose ``applied`` seq shows the step that acted on it
(what a browser shows one image decode later). The step rate is the steps per second the frames show. Both clients
read every frame, as two pages would; the run's episodes are appended to ``--out`` (a temporary file by default).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

from cogail_jax.apps.options import file_out, positive

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))


def client_loop(client, keys_cycle, steps: int, every: int, hz: float, out: dict) -> None:
    """Read frames until ``steps`` steps have been shown, while a second thread presses the next key at random times
    (every ``every`` steps on average, at any phase of the step clock, as a person would)."""
    import random

    lat, frames, pending, lock, done = [], [], [], threading.Lock(), threading.Event()
    rnd = random.Random(hash(client.seat))

    def presser():
        i = 0
        while not done.is_set():
            time.sleep(rnd.uniform(0.5, 1.5) * every / hz)
            i += 1
            with lock:
                t = time.perf_counter()
                pending.append((client.send(keys=[keys_cycle[i % len(keys_cycle)]]), t))

    v = client.view()
    client.send(start=True, keys=[keys_cycle[0]])
    thread = threading.Thread(target=presser, daemon=True)
    thread.start()
    shown = 0
    while shown < steps:
        v = client.view(v["frame_id"])
        now = time.perf_counter()
        if v["status"] in ("success", "failure"):
            client.next()
            continue
        if v["status"] != "running":
            continue
        frames.append((now, v["t"]))
        shown += 1
        with lock:
            while pending and v["applied"][client.seat] >= pending[0][0]:
                lat.append(now - pending.pop(0)[1])
    done.set()
    thread.join()
    out[client.seat] = {"latency": lat, "frames": frames}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="fetchq")
    p.add_argument("--steps", type=positive, default=300, help="steps to measure (after warm-up)")
    p.add_argument("--hz", type=float, default=None, help="steps per second (default: the task's)")
    p.add_argument("--every", type=positive, default=3, help="frames between key presses")
    p.add_argument("--url", default=None, help="a running `cogail collect` (default: serve one here)")
    p.add_argument("--code-human", default=None)
    p.add_argument("--code-robot", default=None)
    p.add_argument("--out", type=file_out("bench.hdf5"), default=None, help="episodes file (default: a temporary file)")
    p.add_argument("--no-opengl", action="store_true",
                   help="draw an MJX task's frames with the fallback used on machines without OpenGL")
    a = p.parse_args(argv)
    if a.url is not None:
        if not a.url.startswith(("http://", "https://")):
            p.error(f"--url {a.url}: give the table's address, e.g. http://127.0.0.1:8766")
        if given := [o for o, v in (("--out", a.out), ("--hz", a.hz)) if v is not None]:
            p.error(f"{given[0]}: the table at --url records and paces its own episodes: drop {given[0]} or --url")
    import cogail_envs

    try:
        cogail_envs.get_task(a.task)
    except cogail_envs.UnknownTaskError as e:
        p.error(f"--task: {e}")
    if a.no_opengl:
        from cogail_envs.mjx_common import FrameRenderer

        def no_gl(self, *args):
            raise RuntimeError("no OpenGL")
        FrameRenderer._get = no_gl

    from cogail_jax.apps import collect
    from cogail_jax.apps.runs import RunError
    from cogail_jax.data.io import DatasetError

    srv = None
    if a.url is None:
        out = a.out or os.path.join(tempfile.mkdtemp(prefix="collect-bench-"), "bench.hdf5")
        t0 = time.perf_counter()
        try:  # its checks of --out and --hz come before it compiles
            srv = collect.open_table(a.task, out=out, port=0, hz=a.hz, gap=0.0, log=lambda *x: None)
        except (RunError, DatasetError) as e:
            p.error(str(e) if str(e).startswith("--") else f"--out: {e}")
        print(f"compiled and warmed up in {time.perf_counter() - t0:.1f} s")
        threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True).start()
        url = f"http://127.0.0.1:{srv.server_address[1]}"
    else:
        url = a.url
    try:
        clients = [collect.Client(url), collect.Client(url)]
        for c, seat, code in ((clients[0], "human", a.code_human), (clients[1], "robot", a.code_robot)):
            try:
                c.join(seat, code)
            except collect.Refused as e:
                p.error(f"--url {url} refused the {seat} seat: {e}")
            except OSError as e:
                p.error(f"--url {url} does not answer ({getattr(e, 'reason', e)}): start `cogail collect` there or "
                        "give its address")
        cfg = clients[0].config()
        env = cogail_envs.make_env(a.task)
        keys = {}
        for c in clients:
            ks = [k for k in cfg["seats"][c.seat]["keys"] if k.startswith(("Arrow", "Key"))]
            keys[c.seat] = ks[:4] or cfg["seats"][c.seat]["keys"][:1]
        res: dict = {}
        threads = [threading.Thread(target=client_loop, args=(c, keys[c.seat], a.steps, a.every, float(cfg['hz']), res)) for c in clients]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for c in clients:
            c.leave()
    finally:
        if srv is not None:
            collect.close(srv)
    lat = [x * 1000 for s in res.values() for x in s["latency"]]
    rates = []
    for s in res.values():  # steps per second over runs of one episode (an episode's end resets t)
        fr = s["frames"]
        runs, start = [], 0
        for i in range(1, len(fr) + 1):
            if i == len(fr) or fr[i][1] <= fr[i - 1][1]:
                if i - start > 5:
                    runs.append((fr[i - 1][1] - fr[start][1], fr[i - 1][0] - fr[start][0]))
                start = i
        rates.append(sum(n for n, _ in runs) / max(1e-9, sum(d for _, d in runs)))
    q = statistics.quantiles(lat, n=20) if len(lat) >= 2 else [float("nan")] * 19
    print(f"task {a.task} ({env.name}), {cfg['hz']:g} steps/s asked, two clients, {a.steps} frames each")
    print(f"step rate: {min(rates):.2f} steps/s (frames seen by each client: "
          f"{', '.join(f'{r:.2f}' for r in rates)})")
    if not lat:
        raise SystemExit(f"no key press was answered within {a.steps} frames: give more --steps, e.g. "
                         f"{max(300, 10 * a.every)}")
    print(f"press-to-frame latency: median {statistics.median(lat):.1f} ms, p95 {q[18]:.1f} ms ({len(lat)} presses)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
