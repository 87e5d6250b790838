"""What is done to a clip before its files are written (docs/generation.md, "Delivering a clip"):
feet planted, a frame rate, a loop, root motion, and separately generated clips joined."""
