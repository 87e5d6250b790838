"""M2D2M as a library: skeletons, the motion representation, models, sampling, metrics, export.

This package depends only on NumPy, PyTorch and (for rendering) Matplotlib; Ray, Lightning and
MLflow live in the packages above it.
"""

__version__ = "0.1.0"
