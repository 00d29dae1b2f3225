"""Human in the loop: ``cogail play`` serves a local web page on which a person drives the human agent.

The robot acts live from pi_R(s, psi(h)): the replay protocol's robot step (``rollouts.make_robot_step``), with
the person's actions in place of a recorded human's, so psi reads the live history. The server steps the
environment (one jitted step per tick of the page), renders the frame (the env's ``render``: the
task's ``cameras`` side by side, or its one view) and answers with psi's code, the step count and the outcome.

Protocol (the paper's): with several ``--run`` the trials cycle through the policies in shuffled blocks (seeded)
and the page names them only "policy A, B, ..."; every finished trial (success, time-out or "end trial") is
appended to the trials file in the project's dataset schema, with the method, run, seed, checkpoint and policy
label as attributes of the demo, so ``cogail eval --run DIR --replay-file TRIALS`` replays people's trials.

All JAX and OpenGL work runs on one worker thread (an OpenGL context belongs to one thread); the HTTP
threads only parse requests and wait for it.
"""
from __future__ import annotations

import json
import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..runtime import checkpoint as ckpt
from ..data import io as data
from ..eval import rollouts
from ..eval import protocol
from ..algo.config import TrainConfig
from .runs import RunError
from . import controls
from .controls import (HELP, HOST, KEYS_2D, KEYS_6D, discrete_action, human_action, human_position,  # noqa: F401
                       png_data_url, render_frame)

LABELS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"


def robot_key(env, rng: np.random.Generator) -> tuple:
    """The robot step's extra argument: a key for a discrete robot's draw (``actions.act``), none for a continuous
    robot (its mean)."""
    if getattr(env, "robot_action_discrete", False):
        return (jax.random.PRNGKey(int(rng.integers(2**31))),)
    return ()


# ---------------------------------------------------------------------------------------------- runs
def read_run_config(run_dir: str | Path, task: str | None = None) -> TrainConfig:
    """The run's config; ``ConfigError`` if ``run_dir`` is not a run or its config is damaged (``TrainConfig.load``),
    ``RunError`` if it belongs to another task than ``task``."""
    run_dir = Path(run_dir)
    cfg = TrainConfig.load(run_dir / "config.json")
    if task is not None and cfg.task != task:
        raise RunError(f"{run_dir} holds a {cfg.task} checkpoint, not {task}: pass --task {cfg.task} or a {task} run")
    return cfg


def pick_checkpoint(run_dir: Path, cfg: TrainConfig, steps: list[int], which: str = "best") -> tuple[int, int]:
    """(seed index, checkpoint step). ``which``: "best" (the checkpoint selected on validation, and its best seed
    there, when the run was evaluated, else the latest), "latest", or an update number."""
    trained = [s for s in steps if s > 0] or steps
    if which not in ("best", "latest"):
        if not which.isdigit() or int(which) not in steps:
            raise RunError(f"{run_dir} has no checkpoint {which!r}: pass --checkpoint best, latest or one of {steps}")
        return 0, int(which)
    res_path = run_dir / "results.json"
    if which == "best" and res_path.exists():
        try:
            seed, step = protocol.selected_checkpoint(json.loads(res_path.read_text()))
            if step in steps:
                return (list(cfg.seeds).index(seed) if seed in cfg.seeds else 0), step
        except (KeyError, ValueError, json.JSONDecodeError):
            pass
    return 0, trained[-1]


@dataclass
class Policy:
    """One run's robot: parameters of one seed at one checkpoint and its jitted robot step."""

    label: str
    run: Path
    method: str
    seed: int
    checkpoint: int
    history: int
    params: dict
    norm: dict
    step: Callable  # (params, norm, state, hist, prev_ah, a_h) -> (state, hist, z, a_r)


def load_policy(run_dir: str | Path, cfg: TrainConfig, label: str, which: str = "best") -> tuple[Policy, object]:
    """Restore a run's checkpoint; returns the policy and the run's environment."""
    from .runs import Policies, build

    run_dir = Path(run_dir)
    s = build(cfg, need_heldout=False, run_dir=run_dir, need_demos=False)  # no demonstration file is read
    store = Policies(run_dir, s)
    steps = store.steps()
    if not steps:
        raise RunError(f"{run_dir} has no checkpoints yet: train it first")
    i, step = pick_checkpoint(run_dir, s.cfg, steps, which)
    try:
        tree = store.load(step)
    except ckpt.CheckpointError as e:
        raise RunError(f"{e}; pass another --checkpoint or --run, or retrain the run")
    one = lambda tree: jax.tree.map(lambda x: np.asarray(x[i]), tree)  # noqa: E731  (host arrays: see on_host)
    _, robot_step = rollouts.make_robot_step(s.cfg, s.env, s.nets)
    policy = Policy(label, run_dir, cfg.method, int(cfg.seeds[i]), int(step), cfg.history,
                    one(tree["params"]), one(tree["norm"]), jax.jit(robot_step))
    return policy, s.env


# ---------------------------------------------------------------------------------------------- the game
class Game:
    """One person's study: trials cycle through the policies in shuffled blocks; each finished trial is
    appended to the trials file. Not thread-safe: call it from one thread."""

    def __init__(self, env, policies: list[Policy], trials: str | Path, max_steps: int | None = None, seed: int = 0):
        from cogail_envs import jitted

        self.env, self.policies, self.trials = env, policies, Path(trials)
        self.max_steps = min(int(max_steps or env.max_episode_steps), env.max_episode_steps)
        self.rng = np.random.default_rng(seed)
        self.order: list[int] = []
        self.saved = self._count_saved()
        self._reset = jitted(env, "reset_from")
        self.new_trial()

    def _count_saved(self) -> int:
        if not self.trials.exists():
            return 0
        import h5py

        with h5py.File(self.trials, "r") as f:
            return len([k for k in f.get("data", {}) if k.startswith("demo")])

    def new_trial(self) -> None:
        if not self.order:  # a new block: every policy once, in random order
            self.order = [int(i) for i in self.rng.permutation(len(self.policies))]
        self.policy = self.policies[self.order.pop()]
        self.init = np.asarray(self.env.sample_init(jax.random.PRNGKey(int(self.rng.integers(2**31)))), np.float32)
        self.state = self._reset(jnp.asarray(self.init))
        self.hist = jnp.repeat(self.state.obs[None], self.policy.history + 1, 0)
        self.prev_ah = jnp.zeros((self.env.human_action_size,), jnp.float32)
        self.obs, self.ah, self.ar = [], [], []
        self.z: list[float] | None = None
        self.status, self.end = "ready", None  # ready | running | success | failure
        self.trial = self.saved + 1
        self._frame = None

    def step(self, a_h: np.ndarray, start: bool = False) -> None:
        """One env step with the person's action (the first non-zero action or ``start`` starts the trial)."""
        discrete = bool(getattr(self.env, "human_action_discrete", False))  # its idle action is not zero
        if self.status == "ready" and (start or (not discrete and np.any(a_h != 0))):
            self.status = "running"
        if self.status != "running":
            return
        p = self.policy
        a_h = jnp.asarray(a_h, jnp.float32)
        nxt, self.hist, z, a_r = p.step(p.params, p.norm, self.state, self.hist, self.prev_ah, a_h, *robot_key(
            self.env, self.rng))
        self.obs.append(np.asarray(self.state.obs))
        self.ah.append(np.asarray(a_h))
        self.ar.append(np.asarray(a_r))
        self.state, self.prev_ah, self.z = nxt, a_h, [float(v) for v in np.asarray(z)]
        self._frame = None
        success = float(nxt.metrics["success"]) > 0
        if float(nxt.done) > 0 or len(self.obs) >= self.max_steps:  # a task may go on after success (a score)
            self.finish("success" if success else "timeout")
        elif success and not self.env.score_metric:
            self.finish("success")

    def finish(self, end: str = "ended") -> None:
        """End the running trial and append it to the trials file."""
        if self.status != "running" or not self.obs:
            return
        m = jax.device_get(self.state.metrics)
        success = float(m["success"]) > 0
        p = self.policy
        attrs = {"method": p.method, "run": str(p.run.resolve()), "seed": p.seed, "checkpoint": p.checkpoint,
                 "policy": p.label, "success": int(success), "end": end, "time": time.strftime("%Y-%m-%d %H:%M:%S"),
                 **{f"metric_{k}": float(v) for k, v in m.items()}}
        data.append_demo(self.trials, self.env, np.stack(self.obs), np.stack(self.ah), np.stack(self.ar), self.init,
                         int(self.env.classify_strategy(self.state.metrics)), attrs)
        self.saved += 1
        self.status, self.end = ("success" if success else "failure"), end

    def view(self) -> dict:
        """What the page shows (never the method or the run: the protocol is blind)."""
        if self._frame is None:
            self._frame = png_data_url(render_frame(self.env, self.state))
        return {"status": self.status, "end": self.end, "t": len(self.obs), "max_steps": self.max_steps,
                "policy": self.policy.label, "trial": self.trial, "saved": self.saved, "z": self.z,
                "human": human_position(self.env, self.state), "frame": self._frame}


# ---------------------------------------------------------------------------------------------- the server
class App:
    """The game behind a single worker thread, and the page's settings."""

    def __init__(self, hz: float):
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cogail-play")
        self.game: Game | None = None
        self.hz = hz

    def call(self, fn, *args):
        return self.pool.submit(fn, *args).result()

    def config(self) -> dict:
        env = self.game.env
        from cogail_envs import get_task

        task = get_task(env.name)
        if getattr(env, "human_action_discrete", False):
            keys, text = sorted({*task.play_keys, "Enter"}), task.play_help + "\nEnter: start / next trial"
        else:
            six = env.human_action_size > 2
            keys = sorted({*(KEYS_6D if six else KEYS_2D), "Space", "Enter"})
            text = HELP["6d" if six else "2d"] + "\nEnter: start / next trial"
        return {"task": env.name, "hz": self.hz, "help": text, "keys": keys, "discrete": bool(
                getattr(env, "human_action_discrete", False)),
                "policies": len(self.game.policies), "legend": [list(x) for x in task.legend]}

    # handlers (run on the worker thread)
    def do_step(self, body: dict) -> dict:
        g = self.game
        start = bool(body.get("start", False))
        if getattr(g.env, "human_action_discrete", False):
            from cogail_envs import get_task

            task = get_task(g.env.name)
            a_h, pressed = discrete_action(g.env.human_action_size, dict(task.play_keys), task.play_idle,
                                           body.get("keys", []), body.get("axes", []), body.get("buttons", []))
            start = start or pressed
        else:
            a_h = human_action(g.env.human_action_size, body.get("keys", []), body.get("axes", []),
                               float(body.get("gripper", 1.0)))
        g.step(a_h, start)
        return g.view()

    def do_end(self, body: dict) -> dict:
        self.game.finish("ended")
        return self.game.view()

    def do_new(self, body: dict) -> dict:
        if self.game.status == "running":
            self.game.finish("ended")
        self.game.new_trial()
        return self.game.view()


PAGE = Path(__file__).with_name("play.html")


class Handler(BaseHTTPRequestHandler):
    server_version = "cogail-play"

    def log_message(self, fmt, *args):  # quiet: one line per request would flood the terminal
        pass

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        try:
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError):  # the page was closed mid-request
            pass

    def _json(self, obj) -> None:
        self._send(200, json.dumps(obj).encode(), "application/json")

    def do_GET(self):  # noqa: N802
        app: App = self.server.app
        if self.path in ("/", "/index.html"):
            self._send(200, PAGE.read_bytes(), "text/html; charset=utf-8")
        elif self.path == "/api/config":
            self._json(app.config())
        elif self.path == "/api/state":
            self._json(app.call(app.game.view))
        else:
            self._send(404, b"not found", "text/plain")

    def do_POST(self):  # noqa: N802
        app: App = self.server.app
        n = int(self.headers.get("Content-Length") or 0)
        try:
            body = json.loads(self.rfile.read(n) or b"{}")
        except json.JSONDecodeError:
            return self._send(400, b"bad json", "text/plain")
        fn = {"/api/step": app.do_step, "/api/end": app.do_end, "/api/new": app.do_new}.get(self.path)
        if fn is None:
            return self._send(404, b"not found", "text/plain")
        self._json(app.call(fn, body))


def bind(port: int) -> ThreadingHTTPServer:
    """Listen on 127.0.0.1:port (0: any free port); ``RunError`` with the fix when the port is taken."""
    return controls.bind(port, Handler)


def check_trials_file(trials: Path, runs, cfgs) -> None:
    """``RunError`` naming the fix if people's trials cannot be appended to ``trials``: a folder there, a folder
    it cannot be written in, or a file a run trains or is evaluated on (its config's files and its data.json's
    sets), which the trials would change."""
    if trials.is_dir():
        raise RunError(f"--trials {trials} is a folder: pass a file, e.g. {trials / 'trials.hdf5'}")
    parent = trials.parent if str(trials.parent) else Path(".")
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise RunError(f"--trials {trials}: cannot write in {parent}: pass a file in a folder you can write")

    def paths(x):
        if isinstance(x, dict):
            for k, v in x.items():
                yield from ([v] if k == "path" and isinstance(v, str) else paths(v))
        elif isinstance(x, list):
            for v in x:
                yield from paths(v)

    target = trials.resolve()
    for r, cfg in zip(runs, cfgs):
        manifest = Path(r) / "data.json"
        try:
            used = list(paths(json.loads(manifest.read_text()))) if manifest.is_file() else []
        except (OSError, json.JSONDecodeError):
            used = []
        used += [f for f in (cfg.demos, cfg.heldout, cfg.validation) if f]
        if any(Path(p).resolve() == target for p in used):
            raise RunError(f"--trials {trials} is a dataset the run {r} trains or is evaluated on; the trials would "
                           "change it: pass another file")


def open_study(runs: list[str | Path], task: str | None = None, port: int = 8765, trials: str | Path | None = None,
                 checkpoint: str = "best", max_steps: int | None = None, hz: float | None = None, seed: int = 0,
                 log=print) -> ThreadingHTTPServer:
    """Check the runs, bind the port, load the policies, compile and warm up; returns the bound server
    (``server.app``), ready for ``serve_forever``."""
    import cogail_envs

    controls.on_host()
    if not runs:
        raise RunError("no run given: pass --run DIR (a training run's directory; repeat it for several)")
    cfgs = [read_run_config(r, task) for r in runs]
    task = task or cfgs[0].task
    for r, c in zip(runs, cfgs):
        if c.task != task:
            raise RunError(f"{r} holds a {c.task} checkpoint but {runs[0]} a {task} one: play one task at a time")
    env = cogail_envs.make_env(task)
    hz = float(hz or cogail_envs.get_task(task).play_hz)
    if not math.isfinite(hz) or not 0 < hz <= 240:
        raise RunError(f"--hz {hz:g} is not a usable number of steps per second: pass one above 0, at most 240")
    if not 0 <= seed < 2 ** 32:
        raise RunError(f"--seed {seed}: a seed is an integer from 0 to {2 ** 32 - 1}")
    trials = Path(trials) if trials else Path(runs[0]) / "trials.hdf5"
    check_trials_file(trials, runs, cfgs)
    data.check_appendable(trials, env)
    server = bind(port)
    try:
        app = App(hz)
        labels = np.random.default_rng(seed).permutation(len(runs))
        log(f"loading {len(runs)} polic{'y' if len(runs) == 1 else 'ies'} for {task} and compiling ...")

        def load():
            policies = []
            for r, c, li in zip(runs, cfgs, labels):
                policy, penv = load_policy(r, c, LABELS[li], checkpoint)
                policies.append(policy)
            policies.sort(key=lambda p: p.label)
            game = Game(penv, policies, trials, max_steps, seed)
            for p in policies:  # compile every policy's step (twice: reset's and step's state) and the renderer
                game.policy = p
                game.hist = jnp.repeat(game.state.obs[None], p.history + 1, 0)
                st, h, prev = game.state, game.hist, game.prev_ah
                for _ in range(2):
                    st, h, _, _ = p.step(p.params, p.norm, st, h, prev, jnp.zeros_like(prev),
                                         *robot_key(penv, np.random.default_rng(0)))
                jax.block_until_ready(st.obs)
            game.order = []
            game.new_trial()
            game.view()
            return game

        app.game = app.call(load)
        server.app = app
    except BaseException:
        server.server_close()
        raise
    return server


def close(server: ThreadingHTTPServer) -> None:
    server.server_close()
    server.app.pool.shutdown(wait=True)


def serve(runs, task=None, port=8765, trials=None, checkpoint="best", max_steps=None, hz=None, seed=0) -> int:
    """``cogail play``: serve until Ctrl-C."""
    server = open_study(runs, task, port, trials, checkpoint, max_steps, hz, seed)
    game = server.app.game
    print(f"cogail play: {game.env.name}, {len(game.policies)} polic{'y' if len(game.policies) == 1 else 'ies'} "
          f"(shown as {', '.join(p.label for p in game.policies)}); trials are appended to {game.trials}", flush=True)
    print(f"open http://{HOST}:{server.server_address[1]}/ in a browser (Ctrl-C to stop)", flush=True)
    try:
        server.serve_forever(poll_interval=0.2)
    except KeyboardInterrupt:
        pass
    finally:
        close(server)
    print(f"stopped: {game.saved} trials in {game.trials}; replay them with "
          f"`cogail eval --run {game.policies[0].run} --replay-file {game.trials}`", flush=True)
    return 0


__all__ = ["serve", "open_study", "close", "Game", "Policy", "human_action", "load_policy", "read_run_config"]
