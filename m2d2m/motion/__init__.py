"""A motion and everything done with it, by room: ``clip`` (the Motion a generator returns),
``representation/`` (skeletons, rotations, HumanML3D's features, normalisation, body parts, poses),
``files/`` (the format table and every reader and writer: npy, BVH, glTF, FBX, pictures),
``rigs/`` (someone else's character: joint maps, up axes, retargeting) and ``transforms/`` (what
an animator asks before the files: feet, frame rate, loops, root motion, joining)."""
