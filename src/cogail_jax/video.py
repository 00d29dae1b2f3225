"""Videos of episodes: scripted demonstrations, or a trained run's interpolation rollouts (GIF or MP4)."""
from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np


def _rollout_states(env, policy, init_states, T):
    """Scan a batched policy ``policy(state, t, key) -> action`` from ``init_states``; stack the states."""

    def body(carry, t):
        state, fin, key = carry
        key, k = jax.random.split(key)
        nxt = jax.vmap(env.step)(state, policy(state, t, k))
        keep = lambda a, b: jnp.where(fin.reshape(fin.shape + (1,) * (a.ndim - 1)), a, b)
        state = jax.tree.map(keep, state, nxt)
        return (state, fin | (nxt.done > 0), key), state

    fin = jnp.zeros(init_states.done.shape, bool)
    _, states = jax.lax.scan(body, (init_states, fin, jax.random.PRNGKey(0)), jnp.arange(T))
    return states


def _frames(env, states, num, T):
    frames = []
    for t in range(0, T, 2):
        row = [env.render(jax.tree.map(lambda x: x[t, i], states)) for i in range(num)]
        frames.append(np.concatenate(row, axis=1))
    return frames


def write_video(task: str, out: str | Path, run: str | Path | None = None, num: int = 4, fps: int = 20) -> Path:
    import imageio.v2 as imageio

    import cogail_envs

    from .config import TrainConfig

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if run is None:
        env = cogail_envs.make_env(task)
        keys = jax.random.split(jax.random.PRNGKey(0), num)
        states0 = jax.vmap(env.reset)(keys)
        team = jax.vmap(env.team_init, in_axes=(0, None))(keys, env.uniform_mix())[0]
        team_box = [team]

        def policy(state, t, key):
            ts, a = jax.vmap(env.team_act)(team_box[0], state, jax.random.split(key, num))
            team_box[0] = ts
            return a

        # the scripted team is stateful: run it in a scan of its own
        def body(carry, key):
            state, ts, fin = carry
            ts, a = jax.vmap(env.team_act)(ts, state, jax.random.split(key, num))
            nxt = jax.vmap(env.step)(state, a)
            keep = lambda x, y: jnp.where(fin.reshape(fin.shape + (1,) * (x.ndim - 1)), x, y)
            state = jax.tree.map(keep, state, nxt)
            return (state, ts, fin | (nxt.done > 0)), state

        T = env.max_episode_steps
        _, states = jax.jit(lambda s, ts: jax.lax.scan(body, (s, ts, jnp.zeros((num,), bool)),
                                                        jax.random.split(jax.random.PRNGKey(1), T)))(states0, team)
        del policy
    else:
        from . import checkpoint as ckpt
        from . import evaluate, trainer

        run = Path(run)
        cfg = TrainConfig.load(run / "config.json")
        s = trainer.build(cfg, need_heldout=False)
        env = s.env
        mgr = ckpt.manager(run)
        best = None
        if (run / "results.json").exists():
            best = json.loads((run / "results.json").read_text())["best_checkpoint"][str(cfg.seeds[0])]["interpolation"]
        step = best if best is not None else max(ckpt.steps(mgr))
        state = ckpt.restore(mgr, step, jax.eval_shape(lambda: s.init(cfg.seeds, s.expert)))
        params = jax.tree.map(lambda x: x[0], state.params)
        norm = jax.tree.map(lambda x: x[0], state.norm)
        codes = evaluate.interpolation_codes(cfg.eval_codes)
        z = codes[np.linspace(0, len(codes) - 1, num).astype(int)]
        z = z if cfg.use_code else jnp.zeros_like(z)
        actor = s.nets["actor"].apply

        def policy(st, t, key):
            mean, _ = actor(params["actor"], (st.obs - norm["mean"]) / norm["std"], z)
            return jnp.clip(mean, -1, 1)

        T = env.max_episode_steps
        states0 = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(7), num))
        states = jax.jit(lambda s0: _rollout_states(env, policy, s0, T))(states0)
    frames = _frames(env, states, num, env.max_episode_steps)
    if out.suffix == ".mp4":
        imageio.mimwrite(out, frames, fps=fps, macro_block_size=1)
    else:
        imageio.mimwrite(out, frames, duration=1000 / fps, loop=0)
    return out
