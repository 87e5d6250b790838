"""From a request (action sentences, lengths in frames, seeds) to a Motion, one generator per model."""
