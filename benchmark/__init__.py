"""promptwalk: a benchmark of large language models as low-level robot controllers."""

__version__ = "0.1.0"
