"""The seed axis sharded over several (here: 2 forced CPU) devices gives the single-device result."""
import subprocess
import sys
import textwrap

# The 2-device subprocesses below check program structure (shardings, collectives, compilations), not speed: their
# XLA backend compiles with less optimisation (about half the compile time of the MJX chunk on CPU). The
# collectives come from XLA's SPMD partitioning, which these flags leave alone: the chunk under plain jit sharding
# propagation (the layout the MJX test guards against) compiles to the same two all-reduces with them as without.
# LLVM's expensive passes are off too, as in tests/conftest.py's flags (they act after the HLO is final: the HLO
# text the collective counts read is the same). With the deterministic-GPU flag of every `cogail` command, as there:
# the subprocesses' compilation cache keys are those of the `cogail` runs beside them.
FAST_COMPILE = ("--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false "
                "--xla_llvm_disable_expensive_passes=true --xla_gpu_deterministic_ops=true")


def test_two_devices_match_one(tiny_cfg, tmp_path):
    script = textwrap.dedent(f"""
        import os
        os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2 {FAST_COMPILE}"
        import jax, numpy as np
        from cogail_jax.apps import runs, train_loop
        from cogail_jax.algo.config import TrainConfig
        assert len(jax.devices()) == 2
        cfg = TrainConfig.from_dict({tiny_cfg.to_json()!r} and __import__("json").loads({tiny_cfg.to_json()!r}))
        s = runs.build(cfg, need_heldout=False)
        one = s.init(cfg.seeds, s.expert)
        two, ex2 = train_loop.place_on_devices(s.init(cfg.seeds, s.expert), s.expert, "all", len(cfg.seeds))
        assert len(two.params["actor"]["params"]["log_std"].sharding.device_set) == 2
        one, _ = s.chunk(one, s.expert)
        two, _ = s.chunk(two, ex2)
        assert len(two.params["actor"]["params"]["log_std"].sharding.device_set) == 2
        for a, b in zip(jax.tree.leaves(jax.device_get(one.params)), jax.tree.leaves(jax.device_get(two.params))):
            np.testing.assert_allclose(a, b, rtol=2e-5, atol=2e-6)
        # the per-device mode (each device runs the one-device program) gives the same result, placed as its input
        pd = runs.build(cfg.replace(multi_device="per_device"), need_heldout=False)
        three, ex3 = train_loop.place_on_devices(pd.init(cfg.seeds, pd.expert), pd.expert, "all", len(cfg.seeds))
        sig = lambda t: [(x.sharding, x.shape, x.dtype, x.weak_type) for x in jax.tree.leaves(t)]
        sig0 = sig(three)
        three, m3 = pd.chunk(three, ex3)
        assert sig(three) == sig0
        assert m3["disc_loss"].shape == (cfg.updates_per_call, len(cfg.seeds))
        for a, b in zip(jax.tree.leaves(jax.device_get(one.params)), jax.tree.leaves(jax.device_get(three.params))):
            np.testing.assert_allclose(a, b, rtol=2e-5, atol=2e-6)
        n = pd.chunk._cache_size()
        three, _ = pd.chunk(three, ex3)
        assert pd.chunk._cache_size() == n == 2, n  # one program per device, compiled once
        print("OK")
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0 and "OK" in r.stdout, r.stderr[-3000:]


def test_sharded_mjx_chunk_has_no_cross_device_collectives(tmp_path):
    """Each device runs its own seeds: the compiled 2-device handover program has no all-reduce / all-gather, and
    its output state is placed as its input was (else every run compiled the chunk a second time).
    (Under plain jit sharding propagation MJX's solver loops reduced their stopping test over both devices in
    every iteration: 2 x H200 ran at 0.25x one.)"""
    script = textwrap.dedent("""
        import os, re
        os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2 FAST_COMPILE"
        import jax
        import numpy as np
        import cogail_envs
        from cogail_jax.data import io as data
        from cogail_jax.data import generate as demos
        from cogail_jax.apps import runs, train_loop
        from cogail_jax.algo.config import TrainConfig
        env = cogail_envs.make_env("handover")
        # two short made-up demonstrations: only their shapes enter the programs under test (the scripted
        # handover rollout that would make real ones compiles for ~30 s on CPU)
        N, L, r = 2, 12, np.random.default_rng(0)
        fake = demos.Episodes(
            obs=r.normal(size=(N, L, env.observation_size)).astype(np.float32),
            actions_human=r.uniform(-1, 1, (N, L, env.human_action_size)).astype(np.float32),
            actions_robot=r.uniform(-1, 1, (N, L, env.robot_action_size)).astype(np.float32),
            length=np.full(N, L), strategy=np.arange(1, N + 1), executed=np.arange(1, N + 1), success=np.ones(N),
            init=np.zeros((N, env.init_size), np.float32), final_metrics={})
        path = data.save_demos("demos.hdf5", env, fake, seed=0)
        cfg = TrainConfig(task="handover", num_envs=2, unroll_length=2, seeds=(1, 2), updates_per_call=1,
                          total_steps=8, bc_steps=0, inner_updates=1, ppo_epochs=1, num_minibatches=1,
                          demos=str(path)).validate()
        s = runs.build(cfg, need_heldout=False)
        st, ex = train_loop.place_on_devices(s.init(cfg.seeds, s.expert), s.expert, "all", 2)
        lowered = s.chunk.lower(st, ex)
        # MJX's zero-size state fields stay outside the program over several devices (they crash XLA's GPU compiler)
        assert any(x.size == 0 for x in jax.tree.leaves(st))
        assert all(0 not in a.shape for a in jax.tree.leaves(lowered.args_info)), "an empty leaf entered the program"
        compiled = lowered.compile()
        txt = compiled.as_text()
        from cogail_jax.runtime import parallel
        st = parallel._strip(st, s.chunk._for(st)[1])
        st2, _ = compiled(st, ex, *s.chunk._extra(s.chunk._mesh(st)))
        sig = lambda t: [(x.sharding, x.shape, x.dtype) for x in jax.tree.leaves(t)]
        assert sig(st2) == sig(st), "the next call would compile again: its inputs are placed differently"
        # the MJX tasks' default on several devices: the one-device program per device (XLA's GPU compiler
        # crashes on the 2-device shard_map program); MJX's empty state fields come back as they went in. The
        # per-device dispatch is shown with a cheap per-seed program over this placed handover state (compiling
        # handover's training program once per device would cost two more MJX compilations; the real chunk's
        # per-device results and compilations are checked on fetchq in test_two_devices_match_one).
        assert cfg.multi_device_mode == "per_device" and s.chunk.multi == "per_device"
        from cogail_jax.runtime.parallel import SeedChunk
        sig1 = lambda t: [(x.sharding, x.shape, x.dtype, x.weak_type) for x in jax.tree.leaves(t)]
        st3, ex3 = train_loop.place_on_devices(s.init(cfg.seeds, s.expert), s.expert, "all", 2)
        assert any(x.size == 0 for x in jax.tree.leaves(st3))
        def bump(st, ex):
            out = jax.tree.map(lambda x: x + 1 if x.size and x.dtype == np.float32 else x, st)
            return out, {"disc_loss": jax.numpy.zeros((1, st.update.shape[0]))}
        per = SeedChunk(bump, multi="per_device")
        before, obs0 = sig1(st3), np.asarray(st3.env_state.obs)
        st3, _ = per(st3, ex3)
        assert sig1(st3) == before
        st3, m3 = per(st3, ex3)
        assert per._cache_size() == 2 and m3["disc_loss"].shape == (1, 2), per._cache_size()
        want = obs0 + np.float32(1) + np.float32(1)  # each seed's block, bumped twice and put back in place
        np.testing.assert_array_equal(np.asarray(st3.env_state.obs), want)
        n = {op: len(re.findall(op + r"(-start)?\\(", txt))
             for op in ("all-reduce", "all-gather", "collective-permute", "all-to-all", "reduce-scatter")}
        print(n)
        assert sum(n.values()) == 0, n
        print("OK")
    """).replace("FAST_COMPILE", FAST_COMPILE)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=900, cwd=tmp_path)
    assert r.returncode == 0 and "OK" in r.stdout, r.stdout[-2000:] + r.stderr[-3000:]
