"""Self-play of a run's co-policy on HR-SeqManip: both agents from the co-policy, deterministic; codes = the
learned per-demonstration codes of the first N training demos (in distribution) and a 4 x 4 grid. Per episode:
success, handover, who opened / placed / closed, the drawer's largest opening, how high the bar was lifted
(m), the episode's length and where the two TCPs ended (world frame).

    python experiments/diag_selfplay.py RUN [N] [STEP]
"""
import sys
from pathlib import Path
import jax, jax.numpy as jnp, numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parent))
from diag_handover import load_run
run, n = Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 16
cfg, s, params, norm, step = load_run(run, int(sys.argv[3]) if len(sys.argv) > 3 else None)
env, actor = s.env, s.nets["actor"].apply
def one(z, key):
    st = env.reset(key)
    z0 = env._obj_pos(st.pipeline_state)[2]
    def body(c, _):
        (st, fin), zmax = c[:2], c[2]
        mean, _ = actor(params["actor"], (st.obs - norm["mean"]) / norm["std"], z)
        nxt = env.step(st, jnp.clip(mean, -1, 1))
        new = jax.tree.map(lambda a, b: jnp.where(fin, a, b), st, nxt)
        zmax = jnp.maximum(zmax, env._obj_pos(new.pipeline_state)[2] - z0)
        return (new, fin | (nxt.done > 0), zmax), None
    (st, _, zmax), _ = jax.lax.scan(body, (st, jnp.array(False), jnp.zeros(())), None, length=env.max_episode_steps)
    import cogail_envs.mjx_common as mc
    return {**st.metrics, "lift": zmax, "t": st.info["t"], "h_tcp": mc.tcp_pos(st.pipeline_state, env.human),
            "r_tcp": mc.tcp_pos(st.pipeline_state, env.robot)}
f = jax.jit(jax.vmap(one))
demo_codes = np.tanh(np.asarray(params["codes"]))[:n]
c = np.linspace(-0.75, 0.75, 4); grid = np.stack(np.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)
WHO = {0: "-", 1: "H", 2: "R", 3: "both"}
for name, Z in (("demo codes", demo_codes), ("grid", grid)):
    m = jax.device_get(f(jnp.asarray(Z, jnp.float32), jax.random.split(jax.random.PRNGKey(0), len(Z))))
    print(f"{run} step {step}: {name}: success {np.mean(m['success']):.2f}")
    for i in range(len(Z)):
        print(f"  z={np.round(Z[i], 2)} succ {int(m['success'][i])} handover {int(m['handover'][i])} opened {WHO[int(m['opened_by'][i])]} "
              f"placed {WHO[int(m['placed_by'][i])]} closed {WHO[int(m['closed_by'][i])]} max_open {float(m['max_open'][i]):.3f} lift {float(m['lift'][i]):.3f} t {int(m['t'][i])} "
              f"human tcp {np.round(m['h_tcp'][i], 2)} robot tcp {np.round(m['r_tcp'][i], 2)}")
