"""Rebuild the example files of the README's "Bring your own demonstrations" walk-through.

    python examples/make_examples.py

writes (scripted fetchq demonstrations, float32, a few tens of KB each):

* ``fetchq_demos.npz`` -- NumPy arrays: ``obs`` (N, T_max, 12) padded, ``actions`` (N, T_max, 4) = human (dx, dy)
  then robot (dx, dy), ``length`` (N,), ``strategy`` (N,), ``init`` (N, 4).
* ``fetchq_robomimic_style.hdf5`` -- robomimic-like layout with other key names: ``data/traj_<i>/obs/{agent_pos,
  treasure_pos,status}``, one concatenated ``actions``, ``reset_params``, attribute ``strategy_id``.
* ``fetchq_robomimic_map.json`` -- the key mapping that imports the HDF5 file (``cogail import --map``).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import h5py
import numpy as np

HERE = Path(__file__).resolve().parent

MAPPING = {
    "_comment": "cogail import key mapping for fetchq_robomimic_style.hdf5: FIELD -> where it is in each demo",
    "group": "data",
    "demo_prefix": "traj_",
    "obs": "obs/agent_pos+obs/treasure_pos+obs/status",
    "actions": "actions",
    "init": "reset_params",
    "strategy": "@strategy_id",
}


def main(num_npz: int = 6, num_hdf5: int = 4) -> None:
    import cogail_envs

    from cogail_jax.data import generate as demos

    env = cogail_envs.make_env("fetchq")
    eps = demos.generate(env, num_npz + num_hdf5, seed=7)
    keep = np.flatnonzero(eps.success > 0)[: num_npz + num_hdf5]
    a, b = keep[:num_npz], keep[num_npz:]
    T = int(eps.length[a].max())
    actions = np.concatenate([eps.actions_human, eps.actions_robot], -1)
    np.savez_compressed(HERE / "fetchq_demos.npz", obs=eps.obs[a, :T].astype(np.float32),
                        actions=actions[a, :T].astype(np.float32), length=eps.length[a].astype(np.int32),
                        strategy=eps.strategy[a].astype(np.int32), init=eps.init[a].astype(np.float32))
    with h5py.File(HERE / "fetchq_robomimic_style.hdf5", "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps({"env_name": "2D-Fetch-Quest", "type": "example"})
        kw = {}  # uncompressed: chunk overhead outweighs gzip at this size
        for j, i in enumerate(b):
            n = int(eps.length[i])
            g = data.create_group(f"traj_{j}")
            o = eps.obs[i, :n].astype(np.float32)
            g.create_dataset("obs/agent_pos", data=o[:, :4], **kw)
            g.create_dataset("obs/treasure_pos", data=o[:, 4:8], **kw)
            g.create_dataset("obs/status", data=o[:, 8:], **kw)  # door flags, carried flags
            g.create_dataset("actions", data=actions[i, :n].astype(np.float32), **kw)
            g.create_dataset("reset_params", data=eps.init[i].astype(np.float32))
            g.attrs["strategy_id"] = int(eps.strategy[i])
            g.attrs["num_samples"] = n
        f.create_group("mask").create_dataset("train", data=np.array([f"traj_{j}" for j in range(len(b))], "S"))
    (HERE / "fetchq_robomimic_map.json").write_text(json.dumps(MAPPING, indent=2) + "\n")
    for p in ("fetchq_demos.npz", "fetchq_robomimic_style.hdf5", "fetchq_robomimic_map.json"):
        print(f"{HERE / p}: {(HERE / p).stat().st_size / 1024:.1f} KB")


if __name__ == "__main__":
    main()
