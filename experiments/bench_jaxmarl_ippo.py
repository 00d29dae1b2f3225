"""JaxMARL's own IPPO on an Overcooked kitchen, timed: the throughput our trainer is put beside in BENCHMARKS.md.

It runs JaxMARL's script unchanged (``baselines/IPPO/ippo_ff_overcooked.py`` of FLAIROx/JaxMARL, which the pip
package does not ship: pass its path) through the script's own ``make_train``, with the script's config file
(``baselines/IPPO/config/ippo_ff_overcooked.yaml``: 16 envs x 128 steps, 4 epochs x 4 minibatches, 64-unit MLPs)
and its ``main``'s way of running seeds (vmapped in one jitted call). Only the imports it needs for logging and
configuration, and that are not installed here, are stood in for: ``hydra`` and ``omegaconf`` (the config is read
from the YAML file), ``wandb`` (its per-update ``log``, still called through the script's host callback, does
nothing), and ``distrax.Categorical`` (the same categorical: sampling, log-probability and entropy from
logits), ``six`` where gymnax's MNIST loader wants it. Env steps per second count every agent-environment step of
every seed, as JaxMARL's ``TOTAL_TIMESTEPS`` does (one step of an env is one step, both agents acting), timed on a
second call after a first one compiled the program.

    python experiments/bench_jaxmarl_ippo.py --script JaxMARL/baselines/IPPO/ippo_ff_overcooked.py \
        --layout cramped_room --seeds 20 --total-steps 1e6 --out ippo.json
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import time
import types
from pathlib import Path

from cogail_jax.apps.options import file_out, positive


def _stand_ins() -> None:
    import jax
    import jax.numpy as jnp

    class Categorical:  # distrax.Categorical(logits=...), the parts the script uses
        def __init__(self, logits):
            self.logits = jax.nn.log_softmax(logits, -1)

        def sample(self, seed):
            return jax.random.categorical(seed, self.logits, -1)

        def log_prob(self, value):
            return jnp.take_along_axis(self.logits, value[..., None].astype(jnp.int32), -1)[..., 0]

        def entropy(self):
            return -jnp.sum(jnp.exp(self.logits) * self.logits, -1)

    mods = {"distrax": {"Categorical": Categorical},
            "hydra": {"main": lambda **kw: (lambda f: f)},
            "omegaconf": {"OmegaConf": types.SimpleNamespace(to_container=lambda c: c)},
            "wandb": {"log": lambda *a, **k: None, "init": lambda *a, **k: None}}
    for name, attrs in mods.items():
        try:
            __import__(name)
        except ImportError:
            m = types.ModuleType(name)
            m.__dict__.update(attrs)
            sys.modules[name] = m
    try:
        import six.moves.urllib.request  # noqa: F401
    except ImportError:
        for name in ("six", "six.moves", "six.moves.urllib", "six.moves.urllib.request"):
            sys.modules[name] = types.ModuleType(name)
        sys.modules["six.moves.urllib.request"].urlretrieve = None


def _config(path: Path) -> dict:
    import yaml

    def num(v):  # OmegaConf reads 5e6 as a number, YAML 1.1 as a string
        if isinstance(v, dict):
            return {k: num(x) for k, x in v.items()}
        try:
            return float(v) if isinstance(v, str) else v
        except ValueError:
            return v

    return num(yaml.safe_load(path.read_text()))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--script", required=True, type=Path, help="JaxMARL's baselines/IPPO/ippo_ff_overcooked.py")
    p.add_argument("--config", type=Path, default=None,
                   help="its YAML config (default: config/ippo_ff_overcooked.yaml beside the script)")
    p.add_argument("--layout", default="cramped_room", help="the kitchen (JaxMARL's overcooked_layouts name)")
    p.add_argument("--seeds", type=positive, default=20, help="seeds vmapped in one call (the script's main: 20)")
    p.add_argument("--total-steps", type=float, default=1e6, help="TOTAL_TIMESTEPS per seed (the config: 5e6)")
    p.add_argument("--out", type=lambda text: Path(file_out("ippo.json")(text)), default=None,
                   help="write the figures here as JSON")
    a = p.parse_args(argv)
    if not a.script.is_file() or a.script.suffix != ".py":
        p.error(f"--script {a.script} is not a Python file: pass the path of JaxMARL's "
                "baselines/IPPO/ippo_ff_overcooked.py")
    config_file = a.config or a.script.parent / "config" / "ippo_ff_overcooked.yaml"
    if not config_file.is_file():
        which = f"--config {config_file}" if a.config else f"--config: {config_file}, beside --script,"
        p.error(f"{which} is not a file: pass --config, the path of JaxMARL's "
                "baselines/IPPO/config/ippo_ff_overcooked.yaml")
    try:
        config = _config(config_file)
    except Exception as e:  # noqa: BLE001 -- YAML's errors, a file that is not text
        p.error(f"--config {config_file} cannot be read as YAML ({type(e).__name__}): pass the script's "
                "ippo_ff_overcooked.yaml")
    need = ("NUM_ENVS", "NUM_STEPS", "ENV_KWARGS")
    if not isinstance(config, dict) or not all(k in config for k in need) or not isinstance(config["ENV_KWARGS"], dict):
        p.error(f"--config {config_file} is not the script's kind of config (no {', '.join(need)}): pass "
                "ippo_ff_overcooked.yaml")
    one_update = int(config["NUM_ENVS"] * config["NUM_STEPS"])
    if not math.isfinite(a.total_steps) or a.total_steps < one_update:
        p.error(f"--total-steps {a.total_steps:g}: give at least one update's steps, {one_update} (NUM_ENVS x "
                f"NUM_STEPS of {config_file.name})")
    _stand_ins()
    import jax

    spec = importlib.util.spec_from_file_location("ippo_ff_overcooked", a.script)
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    except (SyntaxError, ImportError) as e:
        p.error(f"--script {a.script} cannot be loaded ({type(e).__name__}: {str(e).splitlines()[0]}): pass JaxMARL's "
                "baselines/IPPO/ippo_ff_overcooked.py, with jaxmarl installed")
    if not all(hasattr(mod, n) for n in ("make_train", "overcooked_layouts")):
        p.error(f"--script {a.script} has no make_train and overcooked_layouts: pass JaxMARL's "
                "baselines/IPPO/ippo_ff_overcooked.py")
    if a.layout not in mod.overcooked_layouts:
        p.error(f"--layout {a.layout}: no such kitchen; give one of {', '.join(mod.overcooked_layouts)}")
    config["ENV_KWARGS"]["layout"] = mod.overcooked_layouts[a.layout]
    config["TOTAL_TIMESTEPS"] = float(a.total_steps)
    train = jax.jit(jax.vmap(mod.make_train(dict(config))))
    rngs = jax.random.split(jax.random.PRNGKey(30), a.seeds)
    t0 = time.perf_counter()
    jax.block_until_ready(train(rngs))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = jax.block_until_ready(train(rngs))
    second = time.perf_counter() - t0
    steps = int(config["TOTAL_TIMESTEPS"]) // config["NUM_STEPS"] // config["NUM_ENVS"] * config["NUM_STEPS"] \
        * config["NUM_ENVS"] * a.seeds
    ret = out["metrics"]["returned_episode_returns"]
    res = {"layout": a.layout, "seeds": a.seeds, "total_steps_per_seed": int(config["TOTAL_TIMESTEPS"]),
           "num_envs": config["NUM_ENVS"], "num_steps": config["NUM_STEPS"], "env_steps": steps,
           "first_call_s": round(first, 2), "second_call_s": round(second, 2),
           "env_steps_per_s": steps / second, "last_return_mean": float(jax.numpy.mean(ret[:, -1])),
           "device": jax.devices()[0].device_kind}
    print(json.dumps(res, indent=1))
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
