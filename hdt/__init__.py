"""hdt: hierarchically decoupled morphological transfer in pure JAX."""
__version__ = "0.1.0"
