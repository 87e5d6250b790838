"""A motion's files: the table of output formats (formats) and each reader and writer behind it
(npy with its sidecar, BVH, glTF/FBX, GIF/MP4/PNG pictures), each importing its libraries lazily."""
