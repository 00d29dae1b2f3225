"""The seed axis sharded over several (here: 2 forced CPU) devices gives the single-device result."""
import subprocess
import sys
import textwrap


def test_two_devices_match_one(tiny_cfg, tmp_path):
    script = textwrap.dedent(f"""
        import os
        os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
        import jax, numpy as np
        from cogail_jax import trainer
        from cogail_jax.config import TrainConfig
        assert len(jax.devices()) == 2
        cfg = TrainConfig.from_dict({tiny_cfg.to_json()!r} and __import__("json").loads({tiny_cfg.to_json()!r}))
        s = trainer.build(cfg, need_heldout=False)
        one = s.init(cfg.seeds, s.expert)
        two, ex2 = trainer.place_on_devices(s.init(cfg.seeds, s.expert), s.expert, "all", len(cfg.seeds))
        assert len(two.params["actor"]["params"]["log_std"].sharding.device_set) == 2
        one, _ = s.chunk(one, s.expert)
        two, _ = s.chunk(two, ex2)
        assert len(two.params["actor"]["params"]["log_std"].sharding.device_set) == 2
        for a, b in zip(jax.tree.leaves(jax.device_get(one.params)), jax.tree.leaves(jax.device_get(two.params))):
            np.testing.assert_allclose(a, b, rtol=2e-5, atol=2e-6)
        print("OK")
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0 and "OK" in r.stdout, r.stderr[-3000:]
