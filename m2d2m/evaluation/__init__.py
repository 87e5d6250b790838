"""Metrics, the text-motion evaluator network and the measurements of the paper's tables."""
