"""Someone else's character: which of its joints stand for ours (joint maps, found from names and
hierarchy), which way is up, and our motion retargeted onto it (BVH, GLB, FBX)."""
