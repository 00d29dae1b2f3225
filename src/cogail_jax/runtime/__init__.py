"""Runtime: checkpoints, kept programs and the compilation cache, devices and sharding, timing, TensorBoard."""
