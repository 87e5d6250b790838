"""M2D2M (Chi et al. 2024): the generator, its model file, its sampling knobs and its samplers
(Two-Phase Sampling and the baselines). Empty, so that importing the options imports no torch."""
