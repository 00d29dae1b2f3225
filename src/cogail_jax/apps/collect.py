"""Two people at one table: ``cogail collect`` serves a page on which two people drive both agents of a task, and
records every episode as a demonstration in the project's dataset schema.

Each person takes a seat (the human agent's or the robot's) from their own browser, on this machine or on the local
network (``lan``), or one page takes both seats (two key sets or two gamepads). The environment steps on one thread at
a fixed rate (``hz``) with both seats' latest commands: a seat whose input has not been heard for ``hold`` seconds (or
that never acted) holds still (its idle action). An episode starts from the task's own start distribution
(``sample_init``), waits at its start until both seats are taken and one of them acts, and ends on success, failure,
the time limit (``max_steps``), an "End episode" request, or a seat left empty (its browser closed or silent for
``leave`` seconds). Whatever ended it, the episode is appended to the output file (``data.io.append_demo``: through a
temporary copy and ``os.replace``, so a crash loses at most the running episode and never leaves the file unreadable)
with its ``init``, the task's strategy classification, the drivers' anonymous ids, the date and the page's settings.

Protocol (JSON over HTTP; every refusal is a status code and ``{"error": one sentence}``)::

    GET  /api/config                       the task, its keys and help per seat, which seats are taken
    POST /api/join   {seat, code?, id?}    -> {token, seat, id}; 409 taken, 403 wrong or missing code (lan)
    POST /api/input  {token, seq, keys?, axes?, buttons?, gripper?, action?, start?, device?, episode?}
                                           the seat's current command (the full key state; ``action``: a raw
                                           action vector, for scripted clients and other controllers; ``episode``:
                                           the episode the page showed, a command for another one is dropped)
    GET  /api/view?token=T&after=N         long poll: the first frame newer than N (at most ~1 s later)
    POST /api/end | /api/next | /api/leave {token}

A view's ``applied`` names, per seat, the ``seq`` of the input the last step acted on: a client measures the time
from a key press to the frame that shows it from it (``experiments/collect_latency.py`` does, without a browser).

All JAX and rendering work runs on the stepping thread (an OpenGL context belongs to one thread); the HTTP threads
only read and write the seats' inputs under a lock and wait for frames.
"""
from __future__ import annotations

import hmac
import json
import math
import os
import re
import secrets
import socket
import threading
import time
from dataclasses import asdict, dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import jax
import jax.numpy as jnp
import numpy as np

from ..data import io as data
from . import controls
from .runs import RunError

SEATS = ("human", "robot")
CODE_ALPHABET = "ABCDEFGHJKLMNPQRSTUVWXYZ23456789"  # no 0/O, 1/I
CLIENT_ID = re.compile(r"^[A-Za-z0-9_-]{4,40}$")
MAX_BODY = 16 * 1024
DEVICES = ("keyboard", "gamepad", "controller")
PAGE = Path(__file__).with_name("collect.html")


class Refused(Exception):
    """A request the server refuses: an HTTP status and one sentence that says why and what to do."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


@dataclass
class Settings:
    """The page's settings (recorded with every episode)."""

    hz: float
    max_steps: int
    gap: float = 2.0  # seconds an ended episode stays on screen before the next one is set up
    hold: float = 0.5  # seconds a seat's last command is held without news before the seat holds still
    leave: float = 5.0  # seconds without a request after which a seat is empty again (the episode ends)
    lan: bool = False
    seed: int = 0
    port: int = 0


@dataclass
class Seat:
    """One agent's seat: who holds it and their latest input."""

    name: str
    code: str | None = None  # the join code (lan) or None (any local browser may take a free seat)
    token: str | None = None
    client: str = ""
    last_seen: float = 0.0
    heard: float = -math.inf  # when the last input arrived
    seq: int = 0
    keys: frozenset = frozenset()
    tapped: set = field(default_factory=set)  # keys seen since the last step (a tap shorter than a step counts)
    axes: list = field(default_factory=list)
    buttons: list = field(default_factory=list)
    gripper: float = 1.0
    action: np.ndarray | None = None
    start: bool = False
    device: str = ""  # what sent the latest input that acted: keyboard, gamepad or controller ("" idle)

    def take(self, client: str) -> str:
        self.token, self.client, self.last_seen = secrets.token_urlsafe(18), client, time.monotonic()
        self.clear()
        return self.token

    def clear(self) -> None:
        self.heard, self.seq, self.keys, self.tapped, self.axes, self.buttons = -math.inf, 0, frozenset(), set(), [], []
        self.gripper, self.action, self.start, self.device = 1.0, None, False, ""

    def release(self) -> None:
        self.token, self.client = None, ""
        self.clear()


# ---------------------------------------------------------------------------------------------- input
def _numbers(body: dict, key: str, most: int, low: float = -1.0, high: float = 1.0) -> list[float]:
    v = body.get(key, [])
    if not isinstance(v, list) or len(v) > most or not all(isinstance(x, (int, float)) for x in v):
        raise Refused(400, f"'{key}' must be a list of at most {most} numbers")
    out = [float(x) for x in v]
    if not all(math.isfinite(x) for x in out):
        raise Refused(400, f"'{key}' holds a number that is not finite")
    return [min(high, max(low, x)) for x in out]


def parse_input(body: dict, size: int, discrete: bool) -> dict:
    """Validate an input message for an agent with ``size`` actions; a ``Refused`` (400) names the bad field."""
    keys = body.get("keys", [])
    if not isinstance(keys, list) or len(keys) > 32 or not all(isinstance(k, str) and len(k) <= 32 for k in keys):
        raise Refused(400, "'keys' must be a list of at most 32 key names (KeyboardEvent.code)")
    seq = body.get("seq", 0)
    if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq < 2**53:
        raise Refused(400, "'seq' must be a non-negative integer")
    gripper = body.get("gripper", 1.0)
    if isinstance(gripper, bool) or not isinstance(gripper, (int, float)) or not math.isfinite(gripper):
        raise Refused(400, "'gripper' must be a number (>= 0 open, < 0 closed)")
    device = body.get("device", "keyboard")
    if device not in DEVICES:
        raise Refused(400, f"'device' must be one of {', '.join(DEVICES)}")
    episode = body.get("episode")
    if episode is not None and (isinstance(episode, bool) or not isinstance(episode, int)):
        raise Refused(400, "'episode' must be an integer (the episode the command is meant for)")
    action = body.get("action")
    if action is not None:
        a = _numbers(body, "action", 256, -1.0, 1.0)
        if len(a) != size:
            raise Refused(400, f"'action' must hold {size} numbers (this seat's action size), got {len(a)}")
        action = np.asarray(a, np.float32)
        if discrete:  # a discrete agent's choice: the largest entry, one-hot
            action = np.eye(size, dtype=np.float32)[int(np.argmax(action))]
    return {"keys": frozenset(keys), "seq": seq, "gripper": float(gripper), "device": device, "action": action,
            "axes": _numbers(body, "axes", 8), "buttons": _numbers(body, "buttons", 32, 0.0, 1.0),
            "start": bool(body.get("start", False)), "episode": episode}


# ---------------------------------------------------------------------------------------------- the table
class Collector:
    """The shared episode, stepped at a fixed rate on its own thread; each finished episode is appended to ``out``."""

    def __init__(self, env, out: str | Path, settings: Settings, log=print):
        from cogail_envs import get_task, jitted

        self.env, self.task, self.out, self.settings, self.log = env, get_task(env.name), Path(out), settings, log
        self.lock = threading.Condition()
        codes = {s: "".join(secrets.choice(CODE_ALPHABET) for _ in range(6)) if settings.lan else None for s in SEATS}
        self.seats = {s: Seat(s, codes[s]) for s in SEATS}
        self.rng = np.random.default_rng(settings.seed)
        self._reset, self._step = jitted(env, "reset_from"), jitted(env, "step")
        self._classify = jitted(env, "classify_strategy")
        self.saved, self.recorded = self._count_saved(), 0
        self.episode, self.frame_id, self.frame = 0, 0, ""
        self.shown = (0, 0)  # (episode, step) of the frame the pages are shown: what their labels say
        self.request: str | None = None  # "ended" / "next" asked by a page, handled by the stepping thread
        self.stopping = threading.Event()
        self.ready = threading.Event()
        self.error: BaseException | None = None
        self.step_times: list[float] = []
        self.thread = threading.Thread(target=self._run, name="cogail-collect", daemon=True)

    def _count_saved(self) -> int:
        if not self.out.exists():
            return 0
        import h5py

        with h5py.File(self.out, "r") as f:
            return len([k for k in f.get("data", {}) if k.startswith("demo")])

    # ------------------------------------------------------------------ the seats' commands
    def idle(self, seat: Seat) -> np.ndarray:
        return self.command(seat.name, [], [], [], seat.gripper)[0]

    def command(self, agent: str, keys, axes, buttons, gripper: float) -> tuple[np.ndarray, bool]:
        """An agent's action from keys and a gamepad (the pages' mappings), and whether it is a deliberate one."""
        size = getattr(self.env, f"{agent}_action_size")
        if getattr(self.env, f"{agent}_action_discrete", False):
            return controls.discrete_action(size, dict(self.task.play_keys), self.task.play_idle, keys, axes, buttons)
        a = controls.human_action(size, keys, axes, gripper, buttons)
        zero = controls.human_action(size, [], [], gripper)
        return a, bool(np.any(a != zero))

    def _take_command(self, seat: Seat, now: float) -> tuple[np.ndarray, bool]:
        """The seat's command for this step (call under the lock): its latest input if heard within ``hold``, else
        its idle action; the taps since the last step count once."""
        if now - seat.heard > self.settings.hold:
            a, active = self.idle(seat), False
        elif seat.action is not None:
            a = seat.action
            active = bool(np.any(a != self.idle(seat)))
        else:
            a, active = self.command(seat.name, sorted(seat.keys | seat.tapped), seat.axes, seat.buttons, seat.gripper)
        seat.tapped = set()
        active, seat.start = active or seat.start, False
        return a, active

    # ------------------------------------------------------------------ episodes (stepping thread only)
    def _new_episode(self) -> None:
        self.init = np.asarray(self.env.sample_init(jax.random.PRNGKey(int(self.rng.integers(2**31)))), np.float32)
        self.state = self._reset(jnp.asarray(self.init))
        self.obs, self.ah, self.ar = [], [], []
        self.status, self.end, self.next_at = "ready", None, None
        self.drivers: dict[str, str] = {}
        self.devices: dict[str, set] = {s: set() for s in SEATS}
        self.applied = {s: 0 for s in SEATS}
        self.episode += 1
        self.step_times = []
        for seat in self.seats.values():  # the last episode's commands are not this one's: each seat holds still
            seat.tapped, seat.start = set(), False  # until its page sends one for this episode
            seat.heard, seat.keys, seat.action = -math.inf, frozenset(), None

    def _finish(self, end: str) -> None:
        """End the running episode and append it to the output file (nothing is recorded for an episode that never
        stepped)."""
        if self.status != "running":
            return
        m = jax.device_get(self.state.metrics)
        success = float(m["success"]) > 0
        try:
            if self.obs:
                self._append(m, success, end)
        finally:  # the pages see the end once the episode is in the file
            self.status, self.end = ("success" if success else "failure"), end
            self.next_at = time.monotonic() + self.settings.gap

    def _append(self, m: dict, success: bool, end: str) -> None:
        hz = (len(self.step_times) - 1) / (self.step_times[-1] - self.step_times[0]) if len(self.step_times) > 1 else 0
        attrs = {"collector": "cogail collect", "success": int(success), "end": end,
                 "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "episode": self.episode,
                 "human_id": self.drivers.get("human", ""), "robot_id": self.drivers.get("robot", ""),
                 "human_input": ",".join(sorted(self.devices["human"])),
                 "robot_input": ",".join(sorted(self.devices["robot"])),
                 "steps_per_s": round(float(hz), 3), "settings": json.dumps(asdict(self.settings), sort_keys=True),
                 **{f"metric_{k}": float(v) for k, v in m.items()}}
        try:
            data.append_demo(self.out, self.env, np.stack(self.obs), np.stack(self.ah), np.stack(self.ar), self.init,
                             int(self._classify(self.state.metrics)), attrs)
        except OSError as e:  # a full disk, a file taken away: say so, keep serving (the file itself is intact)
            self.log(f"cogail collect: episode {self.episode} could not be appended to {self.out} ({e})")
            return
        self.saved += 1
        self.recorded += 1
        self.log(f"episode {self.episode}: {len(self.obs)} steps, {'success' if success else 'failure'} ({end}), "
                 f"appended to {self.out} "
                 f"({self.saved} episodes)")

    def _render(self) -> None:
        frame = controls.png_data_url(controls.render_frame(self.env, self.state))
        with self.lock:  # the frame, its id and its episode and step change together for the pages' views
            self.frame, self.shown = frame, (self.episode, len(self.obs))
            self.frame_id += 1

    def warm_up(self) -> None:
        """Compile the step and render the first frame (stepping thread)."""
        self._new_episode()
        zero = jnp.concatenate([jnp.asarray(self.idle(self.seats[s])) for s in SEATS])
        st = self._step(self.state, zero)
        jax.block_until_ready(self._step(st, zero).obs)
        int(self._classify(st.metrics))
        self._render()

    def tick(self) -> None:
        """One tick of the fixed rate (stepping thread): seats that fell silent, requests, one env step."""
        now = time.monotonic()
        with self.lock:
            for seat in self.seats.values():
                if seat.token and now - seat.last_seen > self.settings.leave:
                    self.log(f"the {seat.name} seat ({seat.client}) has not been heard for {self.settings.leave:g} s: "
                             "it is free again")
                    seat.release()
            seated = all(s.token for s in self.seats.values())
            request, self.request = self.request, None
            act = None
            if self.status == "running":
                if not seated:
                    request = "left"
                elif request != "ended":
                    act = {s: self._take_command(self.seats[s], now) for s in SEATS}
            elif self.status == "ready":
                cmds = {s: self._take_command(self.seats[s], now) for s in SEATS}
                if seated and any(active for _, active in cmds.values()):
                    self.status, act = "running", cmds
                    self.drivers = {s: self.seats[s].client for s in SEATS}
            if act is not None:
                for s in SEATS:
                    self.applied[s] = self.seats[s].seq
                    if act[s][1] and self.seats[s].device:  # what this step's deliberate commands came from
                        self.devices[s].add(self.seats[s].device)
        changed = False
        if request in ("ended", "left") and self.status == "running":
            self._finish(request)
            changed = True
        elif act is not None:
            a_h, a_r = act["human"][0], act["robot"][0]
            nxt = self._step(self.state, jnp.concatenate([jnp.asarray(a_h), jnp.asarray(a_r)]))
            self.obs.append(np.asarray(self.state.obs))
            self.ah.append(np.asarray(a_h, np.float32))
            self.ar.append(np.asarray(a_r, np.float32))
            self.state = nxt
            self.step_times.append(now)
            success = float(nxt.metrics["success"]) > 0
            if float(nxt.done) > 0 or len(self.obs) >= self.settings.max_steps:
                self._finish("success" if success else "timeout")
            elif success and not self.env.score_metric:
                self._finish("success")
            changed = True
        if self.status in ("success", "failure") and (request == "next" or now >= self.next_at):
            self._new_episode()
            changed = True
        if changed:
            self._render()
            with self.lock:
                self.lock.notify_all()

    def _run(self) -> None:
        try:
            self.warm_up()
        except BaseException as e:  # noqa: BLE001 -- handed to the caller of start()
            self.error = e
            self.ready.set()
            return
        self.ready.set()
        period = 1.0 / self.settings.hz
        due = time.monotonic()
        try:
            while not self.stopping.is_set():
                due += period
                now = time.monotonic()
                if due < now - period:  # fell behind (a slow step): no burst to catch up
                    due = now
                if self.stopping.wait(max(0.0, due - now)):
                    break
                self.tick()
        finally:
            self._finish("stopped")  # Ctrl-C or close(): the running episode is kept

    def start(self) -> None:
        self.thread.start()
        self.ready.wait()
        if self.error is not None:
            raise self.error

    def stop(self) -> None:
        self.stopping.set()
        if self.thread.is_alive():
            self.thread.join()
        with self.lock:
            self.lock.notify_all()

    # ------------------------------------------------------------------ requests (HTTP threads)
    def _seat_of(self, body: dict) -> Seat:
        token = body.get("token")
        if not isinstance(token, str) or not token:
            raise Refused(403, "no seat token: join a seat first (POST /api/join)")
        for seat in self.seats.values():
            if seat.token and hmac.compare_digest(seat.token, token):
                seat.last_seen = time.monotonic()
                return seat
        raise Refused(403, "this seat token is not (or no longer) valid: join a seat again")

    def join(self, body: dict) -> dict:
        name = body.get("seat")
        if name not in SEATS:
            raise Refused(400, f"'seat' must be one of {', '.join(SEATS)}")
        client = body.get("id")
        if not (isinstance(client, str) and CLIENT_ID.match(client)):
            client = "p-" + secrets.token_hex(4)  # anonymous: the page's own id, or one made here
        with self.lock:
            seat = self.seats[name]
            if seat.code is not None:
                code = body.get("code")
                if not isinstance(code, str) or not code:
                    raise Refused(403, f"the {name} seat needs its join code: open the link cogail collect printed")
                if not hmac.compare_digest(code.strip().upper().encode(), seat.code.encode()):
                    raise Refused(403, f"wrong join code for the {name} seat: use the code cogail collect printed")
            if seat.token:
                raise Refused(409, f"the {name} seat is taken: take the other seat, or wait until it is free")
            token = seat.take(client)
            self.lock.notify_all()
        return {"token": token, "seat": name, "id": client}

    def input(self, body: dict) -> dict:
        with self.lock:
            seat = self._seat_of(body)
            agent_size = getattr(self.env, f"{seat.name}_action_size")
            msg = parse_input(body, agent_size, bool(getattr(self.env, f"{seat.name}_action_discrete", False)))
            if msg["seq"] < seat.seq:  # an older message overtaken by a newer one
                return {"ok": True, "stale": True}
            if msg["episode"] is not None and msg["episode"] != self.episode:  # meant for an episode that is over
                return {"ok": True, "stale": True}
            seat.heard = time.monotonic()
            seat.seq, seat.keys, seat.axes, seat.buttons = msg["seq"], msg["keys"], msg["axes"], msg["buttons"]
            seat.tapped |= set(msg["keys"])
            seat.gripper, seat.action = msg["gripper"], msg["action"]
            if msg["action"] is not None:
                seat.device = "controller"
                if len(msg["action"]) >= 7 and not getattr(self.env, f"{seat.name}_action_discrete", False):
                    seat.gripper = float(msg["action"][6])
            elif msg["keys"] or any(msg["axes"]) or any(msg["buttons"]):
                seat.device = msg["device"]
            seat.start = seat.start or msg["start"]
        return {"ok": True}

    def ask(self, body: dict, what: str) -> dict:
        """``ended`` (end the running episode) or ``next`` (set up the next one now)."""
        with self.lock:
            self._seat_of(body)
            self.request = what
        return {"ok": True}

    def leave(self, body: dict) -> dict:
        with self.lock:
            seat = self._seat_of(body)
            self.log(f"the {seat.name} seat ({seat.client}) left")
            seat.release()
            self.lock.notify_all()
        return {"ok": True}

    def config(self) -> dict:
        env = self.env
        seats = {}
        for s in SEATS:
            keys, text, discrete = controls.task_keys(env, self.task, s)
            seats[s] = {"keys": keys, "help": text, "discrete": discrete, "size": getattr(env, f"{s}_action_size")}
        with self.lock:
            taken = {s: bool(self.seats[s].token) for s in SEATS}
        return {"task": env.name, "hz": self.settings.hz, "max_steps": self.settings.max_steps, "lan": self.settings.lan,
                "seats": seats, "taken": taken, "legend": [list(x) for x in self.task.legend],
                "hold": self.settings.hold}

    def view(self, query: dict) -> dict:
        """Long poll: the first frame newer than ``after`` (or the current one after about a second)."""
        token = (query.get("token") or [""])[0]
        try:
            after = int((query.get("after") or ["-1"])[0])
        except ValueError:
            raise Refused(400, "'after' must be an integer (the frame id last seen)")
        deadline = time.monotonic() + 1.0
        with self.lock:
            seat = self._seat_of({"token": token})
            while self.frame_id <= after and not self.stopping.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self.lock.wait(left)
            seat.last_seen = time.monotonic()
            return {"status": self.status, "end": self.end, "episode": self.shown[0], "t": self.shown[1],
                    "max_steps": self.settings.max_steps, "saved": self.saved, "frame_id": self.frame_id,
                    "frame": self.frame, "you": seat.name, "applied": dict(self.applied),
                    "taken": {s: bool(self.seats[s].token) for s in SEATS},
                    "drivers": {s: self.seats[s].client for s in SEATS},
                    "human": controls.human_position(self.env, self.state),
                    "init": [float(x) for x in self.init]}


# ---------------------------------------------------------------------------------------------- the server
class Handler(BaseHTTPRequestHandler):
    server_version = "cogail-collect"

    def log_message(self, fmt, *args):  # quiet: one line per request would flood the terminal
        pass

    def _send(self, code: int, obj) -> None:
        body = obj if isinstance(obj, bytes) else json.dumps(obj).encode()
        self.send_response(code)
        self.send_header("Content-Type", "text/html; charset=utf-8" if isinstance(obj, bytes) else "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        try:
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError):  # the page was closed mid-request
            pass

    def _answer(self, fn, *args) -> None:
        try:
            self._send(200, fn(*args))
        except Refused as e:
            self._send(e.status, {"error": str(e)})

    def do_GET(self):  # noqa: N802
        c: Collector = self.server.collector
        url = urlsplit(self.path)
        if url.path in ("/", "/index.html"):
            self._send(200, PAGE.read_bytes())
        elif url.path == "/api/config":
            self._answer(c.config)
        elif url.path == "/api/view":
            self._answer(c.view, parse_qs(url.query))
        else:
            self._send(404, {"error": f"no such page {url.path}: open / or use the /api/ routes"})

    def do_POST(self):  # noqa: N802
        c: Collector = self.server.collector
        fn = {"/api/join": c.join, "/api/input": c.input, "/api/leave": c.leave,
              "/api/end": lambda b: c.ask(b, "ended"), "/api/next": lambda b: c.ask(b, "next")}.get(self.path)
        if fn is None:
            return self._send(404, {"error": f"no such route {self.path}: use /api/join, input, end, next or leave"})
        try:
            n = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            return self._send(400, {"error": "the Content-Length header is not a number"})
        if n < 0 or n > MAX_BODY:
            self.close_connection = True
            return self._send(413, {"error": f"a message may hold at most {MAX_BODY} bytes"})
        try:
            body = json.loads(self.rfile.read(n) or b"{}")
        except (json.JSONDecodeError, UnicodeDecodeError):
            return self._send(400, {"error": "the message is not JSON: send one JSON object"})
        if not isinstance(body, dict):
            return self._send(400, {"error": "the message must be a JSON object"})
        self._answer(fn, body)


def lan_address() -> str:
    """This machine's address on the local network (the interface of the default route; no packet is sent)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("10.254.254.254", 1))
            return s.getsockname()[0]
        except OSError:
            return socket.gethostbyname(socket.gethostname())


def open_table(task: str, out: str | Path | None = None, port: int = 8766, lan: bool = False, hz: float | None = None,
               max_steps: int | None = None, gap: float = 2.0, hold: float = 0.5, leave: float = 5.0,
               seed: int | None = None, log=print) -> ThreadingHTTPServer:
    """Check the task and the output file, bind the port, compile and warm up; returns the bound server
    (``server.collector``, already stepping), ready for ``serve_forever``."""
    import cogail_envs

    controls.on_host()
    env = cogail_envs.make_env(task)
    spec = cogail_envs.get_task(task)
    out = Path(out) if out else data.data_dir() / f"{env.name}_people.hdf5"
    data.check_appendable(out, env)
    for name, v in (("--hz", hz), ("--gap", gap), ("--hold", hold), ("--leave", leave)):
        positive = name in ("--hz", "--leave")  # 0 steps a second, or a seat left at once, cannot run
        if v is not None and (not math.isfinite(v) or v < 0 or (positive and v == 0)):
            raise RunError(f"{name} {v} is not a usable number of {'steps per second' if name == '--hz' else 'seconds'}:"
                           f" pass {'a positive one' if positive else '0 or more'}")
    hz = float(hz or spec.play_hz)
    if hz > 240:
        raise RunError(f"--hz {hz:g} is faster than a page can show: pass at most 240")
    seed = int.from_bytes(os.urandom(4), "little") if seed is None else int(seed)
    settings = Settings(hz=hz, max_steps=min(int(max_steps or env.max_episode_steps), env.max_episode_steps),
                        gap=float(gap), hold=float(hold), leave=float(leave), lan=bool(lan), seed=seed, port=port)
    server = controls.bind(port, Handler, "0.0.0.0" if lan else controls.HOST)
    settings.port = server.server_address[1]
    try:
        log(f"compiling {env.name} and rendering its first frame ...")
        collector = Collector(env, out, settings, log)
        collector.start()
        server.collector = collector
    except BaseException:
        server.server_close()
        raise
    return server


def close(server: ThreadingHTTPServer) -> None:
    server.collector.stop()
    server.server_close()


def links(server: ThreadingHTTPServer) -> dict[str, str]:
    """The page's address for each seat (with its join code when the table is open to the local network)."""
    c: Collector = server.collector
    port = server.server_address[1]
    host = lan_address() if c.settings.lan else controls.HOST
    out = {}
    for s, seat in c.seats.items():
        out[s] = f"http://{host}:{port}/?seat={s}" + (f"&code={seat.code}" if seat.code else "")
    if not c.settings.lan:
        out["both"] = f"http://{host}:{port}/?seat=both"
    return out


def serve(task: str, out=None, port: int = 8766, lan: bool = False, hz=None, max_steps=None, gap: float = 2.0,
          hold: float = 0.5, leave: float = 5.0, seed=None) -> int:
    """``cogail collect``: serve until Ctrl-C."""
    server = open_table(task, out, port, lan, hz, max_steps, gap, hold, leave, seed)
    c: Collector = server.collector
    print(f"cogail collect: {c.env.name} at {c.settings.hz:g} steps/s, episodes of up to {c.settings.max_steps} steps;"
          f" every episode is appended to {c.out}", flush=True)
    for s, url in links(server).items():
        who = {"both": "one page, both agents (two key sets or two gamepads)"}.get(s, f"the {s} agent")
        code = f" (join code {c.seats[s].code})" if s in c.seats and c.seats[s].code else ""
        print(f"  {who}{code}: {url}", flush=True)
    if c.settings.lan:
        print("open to the local network: only a browser with a seat's join code can drive that agent", flush=True)
    print("Ctrl-C to stop", flush=True)
    try:
        server.serve_forever(poll_interval=0.2)
    except KeyboardInterrupt:
        pass
    finally:
        close(server)
    print(f"stopped: {c.recorded} episodes recorded since it started, {c.saved} in {c.out}; train on them with "
          f"`cogail train --task {c.env.name} --demos {c.out}`", flush=True)
    return 0


# ---------------------------------------------------------------------------------------------- clients
class Client:
    """A client of the page's protocol in Python (no browser): scripted clients, other controllers, benchmarks.
    Each call raises ``Refused`` with the server's status and sentence when the server refuses it."""

    def __init__(self, url: str, timeout: float = 5.0):
        self.url, self.timeout = url.rstrip("/"), timeout
        self.token: str | None = None
        self.seat: str | None = None
        self.seq = 0

    def _call(self, method: str, path: str, body: dict | None = None) -> dict:
        import urllib.error
        import urllib.request

        req = urllib.request.Request(self.url + path, None if body is None else json.dumps(body).encode(),
                                     {"Content-Type": "application/json"}, method=method)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as r:
                return json.loads(r.read())
        except urllib.error.HTTPError as e:
            raise Refused(e.code, json.loads(e.read() or b"{}").get("error", e.reason))

    def config(self) -> dict:
        return self._call("GET", "/api/config")

    def join(self, seat: str, code: str | None = None, client_id: str | None = None) -> dict:
        r = self._call("POST", "/api/join", {"seat": seat, "code": code, "id": client_id})
        self.token, self.seat = r["token"], r["seat"]
        return r

    def send(self, keys=(), action=None, **extra) -> int:
        """Send the seat's current command (keys held, or a raw ``action``); returns its seq."""
        self.seq += 1
        body = {"token": self.token, "seq": self.seq, "keys": list(keys), **extra}
        if action is not None:
            body["action"] = [float(x) for x in np.asarray(action).reshape(-1)]
        self._call("POST", "/api/input", body)
        return self.seq

    def view(self, after: int = -1) -> dict:
        return self._call("GET", f"/api/view?token={self.token}&after={after}")

    def end(self) -> dict:
        return self._call("POST", "/api/end", {"token": self.token})

    def next(self) -> dict:
        return self._call("POST", "/api/next", {"token": self.token})

    def leave(self) -> dict:
        return self._call("POST", "/api/leave", {"token": self.token})


# ---------------------------------------------------------------------------------------------- scripted clients
def scripted_actions(env, init, seed: int, steps: int, step_fn=None) -> tuple[np.ndarray, np.ndarray]:
    """What a scripted pair of people does from ``reset_from(init)``: the task's scripted team
    (``Team.act``, as ``cogail data`` makes demonstrations) played closed-loop in a copy of the episode for ``steps``
    steps; each agent's actions (steps, size). A task without a team: seeded random choices, each held 4 steps.
    ``step_fn``: a jitted ``env.step`` to reuse (one compilation; by default the env's own, ``jitted``)."""
    from cogail_envs import get_task, jitted

    team = get_task(env.name).team
    rng = np.random.default_rng(seed)
    if team is None:
        out = []
        for agent in SEATS:
            size = getattr(env, f"{agent}_action_size")
            if getattr(env, f"{agent}_action_discrete", False):
                a = np.eye(size, dtype=np.float32)[rng.integers(size, size=(steps + 3) // 4)]
            else:
                a = rng.uniform(-1, 1, ((steps + 3) // 4, size)).astype(np.float32)
            out.append(np.repeat(a, 4, 0)[:steps])
        return out[0], out[1]
    cache = env.__dict__.setdefault("_collect_fns", {})
    if "act" not in cache:
        cache["act"] = jax.jit(lambda ts, st, k: team.act(env, ts, st, k))
        cache["init"] = jax.jit(lambda k: team.init(env, k, env.uniform_mix(), 0)[0])
    step = step_fn or jitted(env, "step")
    key = jax.random.PRNGKey(seed)
    ts, state = cache["init"](key), jitted(env, "reset_from")(jnp.asarray(init, jnp.float32))
    acts = []
    for k in jax.random.split(jax.random.fold_in(key, 1), steps):
        ts, a = cache["act"](ts, state, k)
        state = step(state, a)
        acts.append(np.asarray(a, np.float32))
    acts = np.stack(acts)
    return acts[:, : env.human_action_size], acts[:, env.human_action_size:]


__all__ = ["serve", "open_table", "close", "links", "Client", "Collector", "Settings", "Refused", "parse_input",
           "scripted_actions"]
