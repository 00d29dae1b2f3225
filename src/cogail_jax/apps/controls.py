"""What the browser pages share (``cogail play``, ``cogail collect``): key and gamepad mappings to an agent's action,
the rendered frame, and binding the port.

Keys are ``KeyboardEvent.code`` names; gamepads use the browser's standard mapping (axes: left stick 0/1, right stick
2/3, up negative; buttons: 0 A, 4/5 LB/RB, 6/7 LT/RT, 9 start).
"""
from __future__ import annotations

import base64
import errno
import io
from http.server import ThreadingHTTPServer

import numpy as np

from .runs import RunError

HOST = "127.0.0.1"
# keyboard -> (index in the agent's action, sign)
KEYS_2D = {"ArrowRight": (0, 1), "KeyD": (0, 1), "ArrowLeft": (0, -1), "KeyA": (0, -1),
           "ArrowUp": (1, 1), "KeyW": (1, 1), "ArrowDown": (1, -1), "KeyS": (1, -1)}
# MJX tasks: the agent's 6D delta in its base frame (x right, y towards the partner, z up) and the gripper
KEYS_6D = {**KEYS_2D, "KeyE": (2, 1), "KeyQ": (2, -1), "KeyI": (3, 1), "KeyK": (3, -1),
           "KeyO": (4, 1), "KeyU": (4, -1), "KeyJ": (5, 1), "KeyL": (5, -1)}
HELP = {
    "2d": "move: arrow keys or WASD (gamepad: left stick)",
    "6d": "move: WASD or arrows (forward = towards your partner), E/Q up/down\n"
          "rotate: I/K pitch, U/O roll, J/L yaw\nSpace: open / close the gripper\n"
          "gamepad: left stick move, right stick yaw (x) and up/down (y), RT/LT pitch, RB/LB roll, A gripper",
}
# gamepad: the left stick's direction and the A button as the keys a discrete task's ``play_keys`` name
PAD_KEYS = {(0, 1): "ArrowRight", (0, -1): "ArrowLeft", (1, 1): "ArrowDown", (1, -1): "ArrowUp"}


def on_host() -> None:
    """Run every computation that follows on the host's CPU. A page steps one environment at a person's pace, so each
    step's latency is what counts, and an accelerator only adds its launches and transfers to it (on one H200's host,
    press-to-frame median: overcooked 105 ms on the GPU, 86 ms on the host's CPU; fetchq 49 and 45 ms)."""
    import jax

    jax.config.update("jax_default_device", jax.devices("cpu")[0])


def discrete_action(size: int, choices: dict, idle: int, keys, axes=(), buttons=()) -> tuple[np.ndarray, bool]:
    """A discrete agent's one-hot action from the pressed keys: the choice of the last pressed key that the task's
    ``play_keys`` maps (``choices``: key code -> choice), else ``idle`` (e.g. stay); a gamepad's left stick past half
    way and its A button count as the arrow keys and Space. Returns the action and whether a mapped key was pressed
    (which starts a trial)."""
    keys = list(keys)
    ax = np.zeros(2, np.float32)
    ax[: min(2, len(axes))] = np.asarray(list(axes)[:2], np.float32)
    if np.max(np.abs(ax)) > 0.5:
        i = int(np.argmax(np.abs(ax)))
        keys.append(PAD_KEYS[(i, 1 if ax[i] > 0 else -1)])
    if buttons and buttons[0]:
        keys.append("Space")
    mapped = [choices[k] for k in keys if k in choices]
    a = np.zeros(size, np.float32)
    a[mapped[-1] if mapped else idle] = 1.0
    return a, bool(mapped)


def human_action(size: int, keys, axes=(), gripper: float = 1.0, buttons=()) -> np.ndarray:
    """A continuous agent's action from the pressed keys and gamepad axes / buttons (values in [0, 1]).
    2 dims: (dx, dy); 7 dims: 6D delta + gripper (``gripper`` >= 0 open); other sizes: the keys' first dims."""
    a = np.zeros(size, np.float32)
    table = KEYS_2D if size == 2 else KEYS_6D
    for k in keys:
        if k in table and table[k][0] < size:
            i, sign = table[k]
            a[i] += sign
    ax = np.zeros(4, np.float32)
    ax[: min(4, len(axes))] = np.asarray(list(axes)[:4], np.float32)
    a[0] += ax[0]
    if size > 1:
        a[1] -= ax[1]
    if size >= 7:
        b = np.zeros(8, np.float32)
        b[: min(8, len(buttons))] = np.asarray([float(x) for x in list(buttons)[:8]], np.float32)
        a[5] -= ax[2]  # right stick: yaw and up / down
        a[2] -= ax[3]
        a[3] += b[7] - b[6]  # triggers: pitch
        a[4] += b[5] - b[4]  # bumpers: roll
        a[6] = 1.0 if gripper >= 0 else -1.0
    return np.clip(a, -1.0, 1.0)


def task_keys(env, task, agent: str = "human") -> tuple[list[str], str, bool]:
    """The keys a page listens to for one agent of ``env`` (``agent``: human or robot), its help text and whether
    the agent's actions are discrete (a discrete agent takes the task's ``play_keys``)."""
    discrete = bool(getattr(env, f"{agent}_action_discrete", False))
    if discrete:
        return sorted(task.play_keys), task.play_help, True
    six = getattr(env, f"{agent}_action_size") > 2
    return sorted({*(KEYS_6D if six else KEYS_2D), "Space"}), HELP["6d" if six else "2d"], False


# ---------------------------------------------------------------------------------------------- frames
def render_frame(env, state) -> np.ndarray:
    """The task's cameras (``Task.cameras``) side by side, or its one view."""
    from cogail_envs import get_task

    cameras = get_task(env.name).cameras
    if not cameras:
        return env.render(state, width=448, height=448)
    return np.concatenate([env.render(state, width=400, height=300, camera=c) for c in cameras], axis=1)


def png_data_url(img: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(img, np.uint8)).save(buf, format="PNG", compress_level=1)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def human_position(env, state) -> list[float]:
    """Where the human agent is (the env's ``human_position``: e.g. map units, or a TCP in metres)."""
    return [round(float(v), 4) for v in np.asarray(env.human_position(state))]


# ---------------------------------------------------------------------------------------------- the port
def bind(port: int, handler, host: str = HOST) -> ThreadingHTTPServer:
    """Listen on host:port (0: any free port); ``RunError`` with the fix when the port is taken."""
    try:
        server = ThreadingHTTPServer((host, port), handler)
    except OverflowError:
        raise RunError(f"port {port} is out of range: pass --port between 1 and 65535 (or 0 to pick a free one)")
    except OSError as e:
        if e.errno == errno.EADDRINUSE:
            raise RunError(f"port {port} is in use: pass --port N with a free port (or --port 0 to pick one)")
        raise RunError(f"cannot listen on {host}:{port} ({e.strerror}): pass another --port")
    server.daemon_threads = True
    return server
