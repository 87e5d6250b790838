"""MMM (Pinyoanuntapong et al. 2024): the generator, the upper-body editor, its model file, its
parallel decoding and its sampling knobs. Empty, so that importing the options imports no torch."""
