"""Self-play (interpolation) traces of HR-SeqManip from saved parameters, on any machine.

    python experiments/diag_seqmanip_interp.py TRACE.npz RUN/config.json OUT.npz [--grid K]

TRACE.npz is what ``experiments/diag_seqmanip_trace.py`` writes (it carries one checkpoint's parameters and
normaliser, ``params_msgpack``), so a GPU run's policy can be studied without its 300 MB checkpoint. Runs the
interpolation protocol (both agents the co-policy's deterministic mean, one fixed code per episode) for the
centres of a K x K grid of codes over (-1, 1)^2, prints each code's episode metrics (handover, who opened /
placed / closed, success) and writes per-step world-frame TCPs, bar position, drawer opening, actions and
grasp flags to OUT.npz.
"""
from __future__ import annotations

import argparse

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np

import cogail_envs
from cogail_envs import mjx_common as mc
from cogail_jax import train
from cogail_jax.config import TrainConfig


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("trace", help="an .npz written by diag_seqmanip_trace.py")
    p.add_argument("config", help="the run's config.json")
    p.add_argument("out")
    p.add_argument("--grid", type=int, default=5)
    a = p.parse_args()
    cfg = TrainConfig.load(a.config).validate()
    env = cogail_envs.make_env("seqmanip")
    nets = train.make_networks(cfg, env, "lsgan")
    saved = flax.serialization.msgpack_restore(np.load(a.trace)["params_msgpack"].tobytes())
    params, norm = saved["params"], saved["norm"]
    actor = nets["actor"].apply

    def one(z, rng):
        state = env.reset(rng)

        def body(carry, _):
            state, fin = carry
            mean, _ = actor(params["actor"], (state.obs - norm["mean"]) / norm["std"], z)
            act = jnp.clip(mean, -1, 1)
            nxt = env.step(state, act)
            d = state.pipeline_state
            rec = {"r_tcp": mc.tcp_pos(d, env.robot), "h_tcp": mc.tcp_pos(d, env.human), "obj": env._obj_pos(d),
                   "opening": env._opening(d), "a": act, "rg": state.info["robot_grasp"],
                   "hg": state.info["human_grasp"], "hh": state.info["human_handle"], "rh": state.info["robot_handle"]}
            new = jax.tree.map(lambda x, y: jnp.where(fin, x, y), state, nxt)
            return (new, fin | (nxt.done > 0)), rec

        (state, _), rec = jax.lax.scan(body, (state, jnp.array(False)), None, length=env.max_episode_steps)
        return state.metrics, rec

    k = a.grid
    c = jnp.linspace(-1 + 1 / k, 1 - 1 / k, k)
    codes = jnp.stack(jnp.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)
    m, rec = jax.device_get(jax.jit(jax.vmap(one))(codes, jax.random.split(jax.random.PRNGKey(0), codes.shape[0])))
    np.savez_compressed(a.out, codes=np.asarray(codes), **{f"m_{n}": v for n, v in m.items()}, **rec)
    for i in range(codes.shape[0]):
        print(i, np.round(np.asarray(codes[i]), 2), {n: round(float(v[i]), 2) for n, v in m.items()})


if __name__ == "__main__":
    main()
