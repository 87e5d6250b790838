"""What a motion is made of: the two skeletons, rotations, HumanML3D's joints ⇄ features,
normalisation, body parts, the rigid body, a rig's pose, and the smoothing filter they share."""
