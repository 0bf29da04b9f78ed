"""exabricks: volume rendering of adaptive-mesh-refinement data (Wald et al. 2020)."""

__version__ = "0.1.0"
