"""The noise processes, no network: forward corruption, posteriors, losses."""
