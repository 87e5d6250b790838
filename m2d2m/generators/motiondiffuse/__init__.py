"""MotionDiffuse (Zhang et al. 2022): the generator, its model file, its sampling knobs and its
controlled sampler. Empty, so that importing the options imports no torch."""
