"""From a request (action sentences, lengths in frames, seeds) to a Motion: the one protocol every
model answers (protocol), sampling knobs declared (options), the shared token-model generator
(token_model) and editing (edits) here; each model's files in its own subpackage (m2d2m/, mmm/,
motiondiffuse/: generator, checkpoint, options, sampling)."""
