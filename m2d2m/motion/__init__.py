"""The motion representation and its files: skeletons, rotations, features, normalisation, rendering,
export, joining."""
