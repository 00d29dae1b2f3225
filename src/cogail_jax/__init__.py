"""cogail-jax: Co-GAIL in JAX."""
__version__ = "0.1.0"
