"""WebDataset DataModules that feed the models from a processed dataset (docs/data.md), by job:
``shards`` (what is read of a shard directory without streaming it), ``samples`` (a clip into a
sample, samples into a batch), ``feed`` (worker processes and pinned memory for the device),
``passes`` (the resampled training stream, length buckets, one pass for validation and test),
``shard_module`` (what every DataModule over shards shares), then one module per family:
``motion_windows`` (the VQ-VAE's windows) and ``tokens`` (captioned tokens, body-token pairs).
docs/training.md, "Data loading"."""
