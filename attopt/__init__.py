"""attopt: spacecraft attitude determination posed as optimisation problems."""

__version__ = "0.1.0"
