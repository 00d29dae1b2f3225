"""Videos of episodes: scripted demonstrations, or a trained run's interpolation rollouts (GIF or MP4)."""
from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..algo import actions, networks


def _rollout_states(env, policy, init_states, T):
    """Scan a batched policy ``policy(state, prev_obs, t, key) -> action`` from ``init_states`` (``prev_obs``: the
    observation one step before, the first one at the start); stack the states."""

    def body(carry, t):
        state, prev, fin, key = carry
        key, k = jax.random.split(key)
        nxt = jax.vmap(env.step)(state, policy(state, prev, t, k))
        keep = lambda a, b: jnp.where(fin.reshape(fin.shape + (1,) * (a.ndim - 1)), a, b)
        prev, state = jnp.where(fin[:, None], prev, state.obs), jax.tree.map(keep, state, nxt)
        return (state, prev, fin | (nxt.done > 0), key), state

    fin = jnp.zeros(init_states.done.shape, bool)
    _, states = jax.lax.scan(body, (init_states, init_states.obs, fin, jax.random.PRNGKey(0)), jnp.arange(T))
    return states


def _run_rollouts(run: Path, num: int, steps: int | None, task: str | None = None):
    """(env, [(interpolation states, T), (replay states, T)]) for a trained run; the replay row only where the
    run's test split is on disk."""
    from ..eval import rollouts
    from ..eval import protocol
    from . import runs
    from ..algo.config import TrainConfig

    from ..data import io as data
    from ..data import manifest, sets

    cfg = TrainConfig.load(run / "config.json")  # no run, or a damaged config: one sentence
    if task and task != cfg.task:
        raise runs.RunError(f"{run} holds a {cfg.task} checkpoint, not {task}: drop --task or pass a {task} run")
    s = runs.build(cfg, need_heldout=False, run_dir=run, need_demos=False)  # no demonstration file is needed
    env = s.env
    store = runs.Policies(run, s)
    steps_there = store.steps()
    if not steps_there:
        raise runs.RunError(f"{run} has no checkpoints yet: train it first (cogail train --run {run})")
    latest = max(steps_there)
    seed, chosen = None, None
    if (run / "results.json").exists():  # the checkpoint selected on validation, and its best seed there
        seed, chosen = protocol.selected_checkpoint(json.loads((run / "results.json").read_text()))
    si = list(cfg.seeds).index(seed) if seed in cfg.seeds else 0

    def load(step):
        tree = store.load(step)
        return jax.tree.map(lambda x: x[si], tree["params"]), jax.tree.map(lambda x: x[si], tree["norm"])

    T = min(env.max_episode_steps, steps or env.max_episode_steps)
    actor = s.nets["actor"].apply
    # interpolation: codes spread over the grid, the co-policy acts for both agents
    params, norm = load(chosen if chosen in steps_there else latest)
    codes = rollouts.interpolation_codes(cfg.eval_codes)
    z = codes[np.linspace(0, len(codes) - 1, num).astype(int)]
    z = z if cfg.use_code else jnp.zeros_like(z)

    def policy(st, prev, t, key):
        mean, _ = actor(params["actor"], networks.policy_input(norm, jnp.stack([prev, st.obs], -2)), z)
        return actions.act(actions.spec_of(env), mean, key)

    states0 = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(7), num))
    interp = jax.jit(lambda s0: _rollout_states(env, policy, s0, T))(states0)
    try:  # the replay row needs the test split's humans
        test = sets.split_path(cfg, sets.TEST)
        manifest.check(run, {"test": test}, env.version)
    except data.DatasetError as e:
        print(f"no replay row: {e}", flush=True)
        return env, [(interp, T)]
    s.heldout = rollouts.heldout_arrays(data.load_demos(test, env, require_init=True))
    # replay: held-out human trajectories open-loop, the robot from pi_R(s, psi(h)) (the replay protocol's step)
    r_params, r_norm = params, norm  # the same checkpoint: the one selected on validation
    _, robot_step = rollouts.make_robot_step(cfg, env, s.nets)
    h = s.heldout
    idx = np.arange(num) % len(h["init"])
    ah, length = jnp.asarray(h["ah"][idx]), jnp.asarray(h["length"][idx])
    K, Ah = cfg.history, env.human_action_size

    def replay_one(init, ah, length):
        state = env.reset_from(init)

        def body(carry, t):
            state, hist, prev_ah, fin = carry
            a_h = jnp.where(t < length, ah[jnp.minimum(t, ah.shape[0] - 1)], 0.0)
            nxt, hist, _, _ = robot_step(r_params, r_norm, state, hist, prev_ah, a_h)
            state = jax.tree.map(lambda a, b: jnp.where(fin, a, b), state, nxt)
            return (state, hist, a_h, fin | (nxt.done > 0)), state

        carry = (state, jnp.repeat(state.obs[None], K + 1, 0), jnp.zeros((Ah,)), jnp.array(False))
        return jax.lax.scan(body, carry, jnp.arange(T))[1]

    replay = jax.jit(jax.vmap(replay_one, out_axes=1))(jnp.asarray(h["init"][idx]), ah, length)
    return env, [(interp, T), (replay, T)]


def _frames(env, states, num, T):
    frames = []
    for t in range(0, T, 2):
        row = [env.render(jax.tree.map(lambda x: x[t, i], states)) for i in range(num)]
        frames.append(np.concatenate(row, axis=1))
    return frames


def write_video(task: str, out: str | Path, run: str | Path | None = None, num: int = 4, fps: int = 20,
                steps: int | None = None) -> Path:
    """Scripted demonstrations (``run=None``), or a run's rollouts: the top row interpolation rollouts (codes
    spread over the code grid), the bottom row replays (the robot with pi_R(s, psi(h)) against the test human
    trajectories), both at the checkpoint selected on validation and its best seed there (the latest checkpoint
    if the run was not evaluated). ``steps`` caps the episode length rendered."""
    import imageio.v2 as imageio

    import cogail_envs

    from ..runtime.paths import output_file
    from .runs import RunError

    out = Path(out)
    if out.suffix.lower() not in (".gif", ".mp4"):
        raise RunError(f"--out {out}: a video is written as .gif or .mp4: name the file so")
    output_file(out, "--out", "rollouts.gif")
    if run is None:
        env = cogail_envs.make_env(task)
        scripted = cogail_envs.team_of(env)
        keys = jax.random.split(jax.random.PRNGKey(0), num)
        states0 = jax.jit(jax.vmap(env.reset))(keys)  # jitted: an eager vmapped MJX reset dispatches op by op
        team = jax.jit(jax.vmap(lambda k, m: scripted.init(env, k, m), in_axes=(0, None)))(keys, env.uniform_mix())[0]

        # the scripted team is stateful: run it in a scan of its own
        def body(carry, key):
            state, ts, fin = carry
            ts, a = jax.vmap(lambda t, st, k: scripted.act(env, t, st, k))(ts, state, jax.random.split(key, num))
            nxt = jax.vmap(env.step)(state, a)
            keep = lambda x, y: jnp.where(fin.reshape(fin.shape + (1,) * (x.ndim - 1)), x, y)
            state = jax.tree.map(keep, state, nxt)
            return (state, ts, fin | (nxt.done > 0)), state

        T = min(env.max_episode_steps, steps or env.max_episode_steps)
        _, states = jax.jit(lambda s, ts: jax.lax.scan(body, (s, ts, jnp.zeros((num,), bool)),
                                                        jax.random.split(jax.random.PRNGKey(1), T)))(states0, team)
        frames = _frames(env, states, num, T)
    else:  # interpolation rollouts on top, replays below
        env, rows = _run_rollouts(Path(run), num, steps, task)
        frames = [np.concatenate(r, axis=0) for r in zip(*(_frames(env, st, num, T) for st, T in rows))]
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix.lower() == ".mp4":
        imageio.mimwrite(out, frames, fps=fps, macro_block_size=1)
    else:
        imageio.mimwrite(out, frames, duration=1000 / fps, loop=0)
    return out
